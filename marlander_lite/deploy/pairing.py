"""Handing the drones their pads at take-off: the lab config's ``pad_assignment: shortest``.

The paper gives drone ``i`` pad ``i`` (``fixed``, the config's ``pad`` entries). A policy trained with each
episode's starts paired with the pads by the shortest pairing (:mod:`marlander_lite.pad_assignment`, CAPT's
assignment) expects the same in the lab: no two drones whose straight paths cross. The drones are alike, so
:func:`pair_drones_with_pads` hands the config's pads out again once the motion capture has seen every drone
resting where it will take off, and the flight then runs on that config as if it had been written so:
the mission, its estimates, safety rules, landing checks and flight log never learn that a pairing happened.

Take-off is straight up to one height for every drone, so the pairing compares positions seen from above:
``(x, y)`` of each drone at rest with ``(x, y)`` of the pads. A drone or pad body the motion capture has not seen
within the wait stops the command before anything is armed (:class:`PairingError`); nothing flies on a guess.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from marlander_lite.deploy.config import LabConfig
from marlander_lite.deploy.estimation import SwarmEstimator
from marlander_lite.deploy.pose_sources import Clock, PoseSource
from marlander_lite.pad_assignment import shortest_pairing

PAIRING_WAIT_S = 3.0
"""How long :func:`resting_positions` waits for a pose of every drone and pad body (s)."""


class PairingError(RuntimeError):
    """The drones could not be paired with pads (a body the motion capture has not seen); nothing was armed."""


def resting_positions(
    lab: LabConfig, source: PoseSource, clock: Clock, wait_s: float = PAIRING_WAIT_S
) -> tuple[np.ndarray, np.ndarray]:
    """Where the drones rest and where the config's pads of the drones are: two ``(N, 3)`` arrays (m), drone order.

    Reads ``source`` every loop period of ``clock`` until every drone and pad body has a valid pose, at most
    ``wait_s`` seconds. The pads are the ones the drones' config entries name (pad ``j`` of the result is
    ``lab.drones[j].pad``), their top-face centres through the body poses.

    Raises:
        PairingError: some body was not seen, or its pose was rejected, within ``wait_s``.
    """
    estimator = SwarmEstimator(lab)
    start = clock.now()
    while True:
        now = clock.now()
        estimator.ingest(source.read(now))
        estimate = estimator.estimate(now)
        seen_drone = np.isfinite(estimate.pos).all(axis=1) & ~estimate.drone_invalid
        seen_pad = np.isfinite(estimate.pad_pos).all(axis=1) & ~estimate.pad_invalid
        if seen_drone.all() and seen_pad.all():
            return estimate.pos.copy(), estimate.pad_pos.copy()
        if now - start >= wait_s:
            missing = [d.name for d, ok in zip(lab.drones, seen_drone, strict=True) if not ok]
            missing += sorted({p.body for p, ok in zip(lab.drone_pads(), seen_pad, strict=True) if not ok})
            raise PairingError(
                f"pad_assignment: shortest needs every drone and pad body seen by the motion capture; after "
                f"{wait_s:g} s there is no valid pose of {', '.join(missing)}. Nothing was armed. Check that those "
                "rigid bodies are tracked (and named as in the config), or set pad_assignment: fixed."
            )
        clock.sleep_until(now + 1.0 / lab.rates.loop_hz)


def pair_drones_with_pads(lab: LabConfig, drone_pos: np.ndarray, pad_pos: np.ndarray) -> LabConfig:
    """A copy of ``lab`` whose drones' ``pad`` entries are the shortest pairing of where they rest with the pads.

    Args:
        lab: the lab config; its drones' pads are the pads handed out (pads no drone names stay unused).
        drone_pos: each drone's position ``(N, 3)`` m, drone order.
        pad_pos: the top-face centre ``(N, 3)`` m of each drone's config pad (``lab.drones[j].pad``), drone order.

    Only ``(x, y)`` count: take-off lifts every drone to the same height. The pairing minimises the sum of
    squared horizontal distances (:func:`marlander_lite.pad_assignment.shortest_pairing`); the copy is checked
    as any config is.
    """
    drone_pos, pad_pos = np.asarray(drone_pos, dtype=float), np.asarray(pad_pos, dtype=float)
    n = lab.num_drones
    if drone_pos.shape != (n, 3) or pad_pos.shape != (n, 3):
        raise ValueError(
            f"drone_pos and pad_pos must be ({n}, 3) arrays (one row per drone), got {drone_pos.shape} and "
            f"{pad_pos.shape}."
        )
    order = shortest_pairing(drone_pos[:, :2], pad_pos[:, :2])  # drone order[j] lands on pad j
    pads = [d.pad for d in lab.drones]
    new_pad = dict(zip(order.tolist(), pads, strict=True))
    drones = tuple(dataclasses.replace(d, pad=new_pad[i]) for i, d in enumerate(lab.drones))
    return dataclasses.replace(lab, drones=drones)


def pairing_line(lab: LabConfig, pads: list[str]) -> str:
    """One console line: ``Pads paired with the drones by the shortest paths: cf1 -> pad3, cf2 -> pad2 (as
    configured), ...``; ``pads`` is the pad each drone of ``lab`` flies to, drone order."""
    parts = [
        f"{d.name} -> {pad}" + (" (as configured)" if d.pad == pad else "")
        for d, pad in zip(lab.drones, pads, strict=True)
    ]
    return "Pads paired with the drones by the shortest paths: " + ", ".join(parts) + "."
