"""``marlander swarm train|evaluate``: the shared (any-N) policy of :mod:`marlander_lite.swarm` on the command line.

Examples::

    marlander swarm train --preset shared-quick --out runs/shared --seed 0
    marlander swarm evaluate --shared runs/shared/policy.safetensors --baseline --sizes 2 4 8 16 --out results
    marlander swarm evaluate --centralised data/policies/quick-cpu.safetensors --sizes 2 --inclinations 0 5 10 15 \\
        --out results --stem inclined

The same options work as ``python -m marlander_lite.swarm.train`` and ``python -m marlander_lite.swarm.evaluation``.
"""

from __future__ import annotations

import argparse


def register(subparsers: argparse._SubParsersAction) -> None:
    swarm = subparsers.add_parser(
        "swarm",
        help="train or evaluate a policy shared by every drone, for swarms of any size (docs/scaling.md)",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    actions = swarm.add_subparsers(dest="action", metavar="ACTION", required=True)
    train = actions.add_parser("train", help="train a shared policy with PPO (drones as batch entries)")
    evaluate = actions.add_parser("evaluate", help="success, error, time, separation vs N, speed or inclination")
    from marlander_lite.swarm import evaluation
    from marlander_lite.swarm import train as training

    training.add_arguments(train)
    evaluation.add_arguments(evaluate)
    train.set_defaults(func=_train)
    evaluate.set_defaults(func=_evaluate)


def _train(args: argparse.Namespace) -> int:
    from marlander_lite.swarm.train import run

    run(args)
    return 0


def _evaluate(args: argparse.Namespace) -> int:
    from marlander_lite.swarm.evaluation import run

    run(args)
    return 0
