"""``gvt model update``: a rig's parameters updated against a session's (or a modes file's) measured modes.

The measured modes come from ``gvt modal``'s chain (issue 20): a session log's accepted hits -> FRFs
(``daq/studies/frf.py frf_from_log``) -> pLSCF + LSFD (``daq/studies/modal.py modal_from_frf``), or the modes file
``gvt modal --modes-out`` wrote. The updating itself is ``analysis/model/updating.py``; this module reads the
inputs, and writes the updated rig TOML with its provenance (docs/model-updating.md).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path

from analysis.errors import BadInput
from analysis.model.rig import Rig
from analysis.model.updating import MeasuredModes, Progress, UpdateResult, select_parameters, update, updated_toml

LOW_HZ = 2.0  # the lower edge of the band modes are identified in, as `gvt modal`


@dataclass
class UpdateRun:
    rig_path: Path
    source: Path
    measured: MeasuredModes
    result: UpdateResult
    text: str  # the updated rig TOML


def measured_from_source(
    source: Path, rig: Rig, band: tuple[float, float] | None = None, progress: Progress | None = None
) -> MeasuredModes:
    """A modes JSON (``gvt modal --modes-out``) is read; anything else is a session log, identified like ``gvt modal``:
    ``band`` None is its default, 2 Hz to the FRFs' top (1000 Hz, or fs / 2.56 when lower: ``default_band``)."""
    if source.suffix.lower() == ".json":
        try:
            doc = json.loads(source.read_text())
        except FileNotFoundError:
            raise BadInput(f"{source}: file not found") from None
        except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
            raise BadInput(f"{source}: not a modes file of `gvt modal --modes-out` ({exc})") from None
        if not isinstance(doc, dict):
            raise BadInput(f"{source}: not a modes file of `gvt modal --modes-out` (no freq_hz)")
        return MeasuredModes.from_json(doc, str(source))
    if not source.exists():
        raise BadInput(f"{source}: file not found")
    from daq.studies.frf import frf_from_log
    from daq.studies.modal import modal_from_frf, modes_json

    fr = frf_from_log(source, rig, band_hz=None if band is None else band[1],
                      progress=None if progress is None else (lambda f: progress("hits", f)))  # fmt: skip
    band = (LOW_HZ, fr.band_hz) if band is None else band
    if fr.frf is None:
        refused = sum(h["verdict"] != "accepted" for h in fr.hits)
        raise BadInput(f"{source}: no accepted hit to build FRFs from ({refused} refused; `gvt frf {source}` says why)")
    run = modal_from_frf(fr.frf, rig, band[0], band[1], source=str(source), driving=fr.driving)
    if not run.rows:
        raise BadInput(f"{source}: no mode identified in {band[0]:g}-{band[1]:g} Hz; see `gvt modal {source}`")
    return MeasuredModes.from_json(modes_json(run), str(source))


def run_update(rig: Rig, rig_path: Path, source: Path, *, params: list[str] | None = None, objective: str | None = None,
               n_modes: int | None = None, optimiser: str = "de", band: tuple[float, float] | None = None,
               progress: Progress | None = None) -> UpdateRun:  # fmt: skip
    """Measured modes of ``source`` -> updated parameters -> the updated rig file's text."""
    chosen = select_parameters(rig.config, params)
    measured = measured_from_source(source, rig, band, progress)
    result = update(rig.config, measured, chosen, objective=objective, n_modes=n_modes, optimiser=optimiser, progress=progress,
                    path=rig_path)  # fmt: skip
    date = datetime.now(UTC).isoformat(timespec="seconds")
    text = updated_toml(Path(rig_path).read_text(), result, result.provenance(str(rig_path), str(source), date))
    return UpdateRun(Path(rig_path), source, measured, result, text)


def summary(run: UpdateRun) -> dict:
    r = run.result
    return {
        "rig": str(run.rig_path), "source": str(run.source), "objective": r.objective, "optimiser": r.optimiser,
        "objective_nominal": r.nominal_value, "objective_value": r.objective_value, "evaluations": r.evaluations,
        "seconds": r.seconds, "affine_model": r.affine, "parameters": r.value_rows(), "modes": r.rows(), "notes": r.notes,
    }  # fmt: skip


def table_text(run: UpdateRun) -> str:
    r = run.result
    lines = [f"{'parameter':<12} {'target':<26} {'nominal':>12} {'updated':>12} {'change':>8} {'1-sigma':>10}"]
    for row in r.value_rows():
        sig = f"{row['sigma']:>10.4g}" if "sigma" in row else f"{'-':>10}"
        lines.append(f"{row['name']:<12} {row['target']:<26} {row['nominal']:>12.6g} {row['value']:>12.6g} "
                     f"{100 * (row['value'] / row['nominal'] - 1):>+7.3f}% {sig}")  # fmt: skip
    lines.append("")
    lines.append(f"{'mode':>4} {'FE':>3} {'measured [Hz]':>14} {'model [Hz]':>11} {'eq.4.5 term':>12} {'MAC':>6}")
    for m in r.rows():
        mac = f"{m['mac']:>6.3f}" if "mac" in m else f"{'-':>6}"
        lines.append(
            f"{m['mode']:>4} {m['fe_mode']:>3} {m['measured_hz']:>14.3f} {m['model_hz']:>11.3f} {m['residual']:>+12.2e} {mac}"
        )
    lines.append("")
    lines.append(f"objective {r.objective}: {r.nominal_value:.4g} (nominal) -> {r.objective_value:.4g} (updated); "
                 f"{r.evaluations} model solves in {r.seconds:.1f} s ({r.optimiser})")  # fmt: skip
    return "\n".join(lines)
