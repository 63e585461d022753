"""Shipped artifacts that reproduce: retrain every shipped policy from its recorded config and compare.

Each policy in ``data/policies/NAME.safetensors`` has its run in ``data/runs/NAME/`` whose
``config.json`` holds the resolved :class:`~marlander_lite.training.presets.TrainConfig`. The manifest
``data/shipped.json`` records, per artifact, the digest of the policy's content
(:func:`~marlander_lite.training.provenance.policy_digest`) and the commit that shipped it (runs trained
since provenance was recorded also name the commit that trained them in their ``config.json``).

:func:`check_shipped` retrains artifacts (as sweep jobs: processes here or Ray tasks) and says, for each,

- ``identical``: today's code makes a policy with the same digest (bit-identical weights);
- ``identical weights``: bit-identical weights and normaliser, but the file's description differs (for example a
  contract field added to the format since it was shipped);
- ``equivalent``: different weights (e.g. another CPU's floating point) but the same behaviour within
  :data:`TOLERANCE` on the same evaluation episodes;
- ``differs``: today's code no longer reproduces it;
- ``not retrainable``: its recipe needs something not shipped (a fine-tune stage's source run).

A fine-tune is retrained from the shipped run it continues (``init_from`` is mapped into ``data/runs``);
fine-tunes made in several stages ship only their last stage, so they are reported as not retrainable.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

from marlander_lite.distributed import Backend, map_jobs
from marlander_lite.policy_file import read_contract
from marlander_lite.training.provenance import policy_digest
from marlander_lite.training.sweep import SeedJob, SeedOutcome, receive_run, run_state, train_seed
from marlander_lite.training.warm_start import is_policy_file

MANIFEST = "shipped.json"
TOLERANCE = {"success_rate": 0.05, "landing_error_mean_cm": 0.5}
"""Largest differences (absolute: success as a fraction, landing error in cm) for ``equivalent``."""


@dataclass(frozen=True)
class ShippedArtifact:
    """One shipped policy and what it takes to retrain it."""

    name: str
    """``quick-cpu``, ``v0.1/quick-cpu``, ...: the policy is ``data/policies/NAME.safetensors``."""
    policy: Path
    run: Path | None
    """Its run folder in ``data/runs`` (config and logs), if shipped."""
    preset: str | None
    config: dict[str, Any] | None
    """The run's recorded TrainConfig (``init_from`` already mapped to the shipped source run)."""
    problem: str | None
    """Why it cannot be retrained; None if it can."""


def shipped_artifacts(data: str | Path = "data") -> list[ShippedArtifact]:
    """Every shipped policy under ``data/policies`` (sub-folders included), sorted by name."""
    data = Path(data)
    artifacts = []
    for policy in sorted((data / "policies").rglob("*.safetensors")):
        name = policy.relative_to(data / "policies").with_suffix("").as_posix()
        run = data / "runs" / name
        preset, config, problem = None, None, None
        if not (run / "config.json").is_file():
            run, problem = None, f"no run folder data/runs/{name} with its config.json"
        elif read_contract(policy).is_shared:
            preset = json.loads((run / "config.json").read_text()).get("preset")
            problem = "a shared (any-N) policy: retrain it with marlander swarm train"
        else:
            record = json.loads((run / "config.json").read_text())
            preset, config = record.get("preset"), dict(record["train"])
            source = config.get("init_from")
            if is_policy_file(source):  # a shipped policy file
                shipped_source = data / "policies" / Path(source).name
                if not shipped_source.is_file():
                    problem = f"it continues the policy {source}, which is not shipped"
                config["init_from"] = str(shipped_source)
            elif source is not None:
                shipped_source = data / "runs" / Path(source).name
                if not (shipped_source / "model.zip").is_file():
                    problem = f"it continues {source}, whose model (model.zip) is not shipped"
                config["init_from"] = str(shipped_source)
        artifacts.append(ShippedArtifact(name, policy, run, preset, config, problem))
    return sorted(artifacts, key=lambda a: a.name)


def write_manifest(data: str | Path = "data", shipped_in: Callable[[Path], str | None] | None = None) -> Path:
    """Write ``data/shipped.json``: each artifact's policy digest, preset and (if known) shipping commit.

    ``shipped_in(path)`` returns the commit that added a file (default: ``git log`` of the repository).
    """
    data = Path(data)
    shipped_in = shipped_in or _commit_that_added
    manifest = {
        a.name: {
            "policy": a.policy.relative_to(data).as_posix(),
            "policy_digest": policy_digest(a.policy),
            "preset": a.preset,
            "shipped_in_commit": shipped_in(a.policy),
            "retrainable": a.problem is None,
            **({"why_not": a.problem} if a.problem else {}),
        }
        for a in shipped_artifacts(data)
    }
    path = data / MANIFEST
    path.write_text(json.dumps(manifest, indent=2) + "\n")
    return path


def _commit_that_added(path: Path) -> str | None:
    import subprocess

    result = subprocess.run(
        ["git", "log", "--diff-filter=A", "--format=%H", "-1", "--", path.name],
        cwd=path.parent,
        capture_output=True,
        text=True,
        check=False,
    )
    return result.stdout.strip() or None


def check_manifest(data: str | Path = "data") -> list[str]:
    """Names of shipped policies whose content no longer matches ``data/shipped.json`` (or is not in it)."""
    data = Path(data)
    manifest = json.loads((data / MANIFEST).read_text())
    changed = [
        a.name
        for a in shipped_artifacts(data)
        if manifest.get(a.name, {}).get("policy_digest") != policy_digest(a.policy)
    ]
    return changed + sorted(set(manifest) - {a.name for a in shipped_artifacts(data)})


def check_shipped(
    names: Sequence[str],
    out: str | Path,
    *,
    data: str | Path = "data",
    backend: Backend = "local",
    workers: int = 1,
    address: str | None = None,
    episodes: int = 200,
    report: Callable[[str], Any] = print,
) -> list[dict[str, Any]]:
    """Retrain the shipped artifacts ``names`` (all if empty) into ``out/NAME`` and compare; writes ``out/report.json``.

    A retrained run already finished in ``out`` is compared without training it again.
    """
    out = Path(out)
    chosen = [a for a in shipped_artifacts(data) if not names or a.name in names]
    unknown = sorted(set(names) - {a.name for a in chosen})
    if unknown:
        allowed = ", ".join(a.name for a in shipped_artifacts(data))
        raise ValueError(f"Unknown shipped artifact(s) {unknown}; shipped: {allowed}.")
    results: dict[str, dict[str, Any]] = {}
    jobs = []
    for artifact in chosen:
        folder = out / artifact.name
        if artifact.problem is not None:
            results[artifact.name] = {"name": artifact.name, "status": "not retrainable", "why": artifact.problem}
        elif run_state(folder) != "done":
            if folder.exists():
                raise FileExistsError(f"{folder} holds an unfinished run; remove it or choose another --out.")
            assert artifact.config is not None
            jobs.append(SeedJob(artifact.config, artifact.preset, str(folder), resume=False))
    for job, outcome in map_jobs(train_seed, jobs, backend=backend, workers=workers, address=address):
        if isinstance(outcome, SeedOutcome) and outcome.packed_run is not None:
            receive_run(outcome.packed_run, Path(job.folder))
        report(f"{Path(job.folder).name}: trained ({getattr(outcome, 'status', outcome)})")
    for artifact in chosen:
        if artifact.name not in results:
            results[artifact.name] = compare(artifact, out / artifact.name / "policy.safetensors", episodes)
            report(f"{artifact.name}: {results[artifact.name]['status']}")
    ordered = [results[a.name] for a in chosen]
    out.mkdir(parents=True, exist_ok=True)
    (out / "report.json").write_text(json.dumps(ordered, indent=2) + "\n")
    return ordered


def compare(artifact: ShippedArtifact, retrained: Path, episodes: int = 200) -> dict[str, Any]:
    """Compare a retrained policy with the shipped one: digest, weights and (if they differ) behaviour."""
    from safetensors.numpy import load_file

    from marlander_lite.training.evaluation import evaluate_policy_file

    result: dict[str, Any] = {"name": artifact.name}
    if not retrained.is_file():
        return {**result, "status": "differs", "why": f"training did not finish ({retrained} is missing)"}
    shipped_digest, new_digest = policy_digest(artifact.policy), policy_digest(retrained)
    result.update(shipped_digest=shipped_digest, retrained_digest=new_digest)
    if shipped_digest == new_digest:
        return {**result, "status": "identical"}
    old_tensors, new_tensors = load_file(artifact.policy), load_file(retrained)
    if old_tensors.keys() != new_tensors.keys() or any(
        old_tensors[k].shape != new_tensors[k].shape for k in old_tensors
    ):
        return {**result, "status": "differs", "why": "the networks have different shapes"}
    result["max_weight_difference"] = max(float(abs(old_tensors[k] - new_tensors[k]).max()) for k in old_tensors)
    if all(np.array_equal(old_tensors[k], new_tensors[k]) for k in old_tensors):
        # Same weights; only the file's description differs (e.g. a contract field added since it was shipped).
        changed = _metadata_differences(artifact.policy, retrained)
        return {**result, "status": "identical weights", "why": f"metadata differs in {', '.join(changed)}"}
    simulator = (artifact.config or {}).get("simulator", "pointmass")
    count = episodes if simulator == "pointmass" else max(20, episodes // 4)
    summaries = {}
    for label, path in (("shipped", artifact.policy), ("retrained", retrained)):
        summaries[label] = asdict(evaluate_policy_file(path, simulator, count))
    result["evaluation"] = summaries
    within = all(abs(summaries["shipped"][k] - summaries["retrained"][k]) <= tol for k, tol in TOLERANCE.items())
    return {**result, "status": "equivalent" if within else "differs"}


def _metadata_differences(a: Path, b: Path) -> list[str]:
    """Keys of the two policy files' metadata (and of their JSON contracts) whose values differ."""
    from safetensors import safe_open

    def flat(path: Path) -> dict[str, Any]:
        with safe_open(str(path), framework="numpy") as handle:
            metadata = dict(handle.metadata() or {})
        contract = json.loads(metadata.pop("contract", "{}"))
        return {**metadata, **{f"contract.{k}": v for k, v in contract.items()}}

    old, new = flat(a), flat(b)
    differ = sorted(k for k in old.keys() | new.keys() if k not in old or k not in new or old[k] != new[k])
    return differ or ["the order of its entries only"]


def markdown_report(results: Sequence[dict[str, Any]]) -> str:
    """:func:`check_shipped`'s results as a Markdown table."""
    lines = ["| artifact | status | detail |", "|---|---|---|"]
    for r in results:
        detail = r.get("why", "")
        if "evaluation" in r:
            s, n = r["evaluation"]["shipped"], r["evaluation"]["retrained"]
            detail = (
                f"success {100 * s['success_rate']:.1f} -> {100 * n['success_rate']:.1f} %, landing error "
                f"{s['landing_error_mean_cm']:.2f} -> {n['landing_error_mean_cm']:.2f} cm, "
                f"max weight difference {r['max_weight_difference']:.3g}"
            )
        elif r["status"] == "identical":
            detail = f"digest {r['retrained_digest'][:12]}"
        lines.append(f"| {r['name']} | {r['status']} | {detail} |")
    return "\n".join(lines)
