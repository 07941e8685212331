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
from daq.studies.update_log import LogModes, modes_from_log


@dataclass
class UpdateRun:
    rig_path: Path
    source: Path
    measured: MeasuredModes
    result: UpdateResult
    text: str  # the updated rig TOML
    log: LogModes | None = None  # what of a log was used (None: a modes file)

    @property
    def notes(self) -> list[str]:
        return (self.log.notes if self.log else []) + self.result.notes

    @property
    def warnings(self) -> list[str]:
        return (self.log.warnings if self.log else []) + self.result.warnings


def modes_from_file(source: Path) -> MeasuredModes:
    """A modes JSON (``gvt modal --modes-out``, or ``{"freq_hz": [...]}`` with an optional ``freq_std_hz``)."""
    try:
        doc = json.loads(source.read_text())
    except FileNotFoundError:
        raise BadInput(f"{source}: file not found") from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise BadInput(f"{source}: not a modes file of `gvt modal --modes-out` ({exc})") from None
    if not isinstance(doc, dict):
        raise BadInput(f"{source}: not a modes file of `gvt modal --modes-out` (no freq_hz)")
    return MeasuredModes.from_json(doc, str(source))


def run_update(rig: Rig, rig_path: Path, source: Path, *, params: list[str] | None = None, objective: str | None = None,
               n_modes: int | None = None, optimiser: str = "de", band: tuple[float, float] | None = None,
               level: str | int | None = None, progress: Progress | None = None) -> UpdateRun:  # fmt: skip
    """Measured modes of ``source`` (a modes JSON, or a session log: daq/studies/update_log.py) -> updated parameters
    -> the updated rig file's text."""
    chosen = select_parameters(rig.config, params)
    log = None
    if source.suffix.lower() == ".json":
        measured = modes_from_file(source)
    else:
        from daq.studies.importing.frfs import frf_file  # a UFF 58 FRF file, or a log gvt import made of one
        from daq.studies.update_log import modes_from_set

        given = frf_file(source) if source.exists() else None
        log = modes_from_set(source, *given, rig, band) if given else modes_from_log(source, rig, band, level, progress)
        measured = log.measured
    result = update(rig.config, measured, chosen, objective=objective, n_modes=n_modes, optimiser=optimiser, progress=progress,
                    path=rig_path)  # fmt: skip
    date = datetime.now(UTC).isoformat(timespec="seconds")
    prov = result.provenance(str(rig_path), str(source), date)
    if log is not None:
        prov["warnings"] = log.warnings + prov["warnings"]
        prov["data"] = log.provenance()
    text = updated_toml(Path(rig_path).read_text(), result, prov)
    return UpdateRun(Path(rig_path), source, measured, result, text, log)


def summary(run: UpdateRun) -> dict:
    r = run.result
    return {
        "rig": str(run.rig_path), "source": str(run.source), "objective": r.objective, "optimiser": r.optimiser,
        "objective_nominal": r.nominal_value, "objective_value": r.objective_value, "evaluations": r.evaluations,
        "seconds": r.seconds, "affine_model": r.affine, "chi2_nu": r.chi2_nu, "parameters": r.value_rows(), "modes": r.rows(),
        "data": run.log.provenance() if run.log else None, "notes": run.notes, "warnings": run.warnings,
    }  # fmt: skip


def table_text(run: UpdateRun) -> str:
    """The parameters (nominal, updated, change, 1-sigma), the paired modes (measured with its 1-sigma, model, eq. 4.5
    term, residual in sigmas, MAC) and the fit against the measurement's uncertainty."""
    r = run.result
    lines = [f"{'parameter':<12} {'target':<26} {'nominal':>12} {'updated':>12} {'change':>8} {'1-sigma':>10}"]
    for row in r.value_rows():
        sig = f"{row['sigma']:>10.4g}" if "sigma" in row else f"{'inf' if row.get('identifiable') is False else '-':>10}"
        lines.append(f"{row['name']:<12} {row['target']:<26} {row['nominal']:>12.6g} {row['value']:>12.6g} "
                     f"{100 * (row['value'] / row['nominal'] - 1):>+7.3f}% {sig}")  # fmt: skip
    lines.append("")
    lines.append(f"{'mode':>4} {'FE':>3} {'measured [Hz]':>14} {'± [Hz]':>8} {'model [Hz]':>11} {'eq.4.5 term':>12} "
                 f"{'z [σ]':>7} {'MAC':>6}")  # fmt: skip
    for m in r.rows():
        mac = f"{m['mac']:>6.3f}" if "mac" in m else f"{'-':>6}"
        std = f"{m['std_hz']:>8.3f}" if "std_hz" in m else f"{'-':>8}"
        z = f"{m['z']:>+7.1f}" if "z" in m else f"{'-':>7}"
        lines.append(f"{m['mode']:>4} {m['fe_mode']:>3} {m['measured_hz']:>14.3f} {std} {m['model_hz']:>11.3f} "
                     f"{m['residual']:>+12.2e} {z} {mac}")  # fmt: skip
    lines.append("")
    lines.append(f"objective {r.objective}: {r.nominal_value:.4g} (nominal) -> {r.objective_value:.4g} (updated); "
                 f"{r.evaluations} model solves in {r.seconds:.1f} s ({r.optimiser})")  # fmt: skip
    dof = len(r.pairs) - len(r.params)
    if r.chi2_nu is not None:
        lines.append(f"fit: residuals {r.chi2_nu**0.5:.2f}x their measurement uncertainty (rms, chi2/dof = {r.chi2_nu:.3g} "
                     f"over {dof} degree(s) of freedom; about 1 when the model explains the data)")  # fmt: skip
    elif r.freq_std_hz is not None:
        lines.append("fit: as many modes as parameters: the fit cannot be judged against the measurement uncertainty")
    if run.log is not None:
        used = f"hit(s) {', '.join(map(str, run.log.hits_used))}" if run.log.hits_used else "the FRF file's set"
        lines.append(f"data: {used} in {run.log.band[0]:g}-{run.log.band[1]:g} Hz"
                     + "".join(f"; {c} left out ({why})" for c, why in run.log.channels_left_out.items()))  # fmt: skip
    return "\n".join(lines)
