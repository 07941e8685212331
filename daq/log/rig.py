"""A rig and its log: the channel table a rig's sensors give a log, and the rig a session attached to it.

Both the service (a session writes the table; a replay analyses with the attached rig) and the offline
studies (``gvt analyze``, ``gvt frf``, ``gvt modal``, ``gvt report``, UFF export) need these, so they live
here, below both, rather than in a study the service would have to import.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from analysis.errors import BadInput
from daq.log.reader import LogReader

if TYPE_CHECKING:  # a reader of a log (report, frf, export, replay) loads neither the writer nor the rig's model here
    from analysis.model.rig import Rig
    from daq.log.writer import ChannelInfo


class AnalyzeError(BadInput):
    """A log that cannot be analysed as asked, e.g. its attached rig is missing or unusable (one line for the user)."""


def channel_infos(rig: Rig) -> list[ChannelInfo]:
    """The log's channel table of a rig: the hammer, then each sensor, with unit, sensitivity, place and DOF."""
    from daq.log.writer import ChannelInfo

    return [
        ChannelInfo(
            name=p.name,
            quantity=p.quantity,
            unit=p.unit,
            sensitivity_mv_per_unit=p.props.sensitivity_mv_per_unit,
            position_m=p.x_model,
            model_dof=p.dof_name,
            sensor_model=p.props.model,
        )
        for p in [rig.hammer, *rig.sensors]
    ]


def rig_from_log(reader: LogReader) -> Rig:
    """The rig the session attached to its log (``rig/*.toml``), validated like any rig file."""
    import tomllib

    from analysis.model.config import RigConfig
    from analysis.model.loader import ConfigError, validate
    from analysis.model.rig import build_rig

    rigs = {name: data for name, (_media, data) in reader.attachments().items() if name.startswith("rig/")}
    if not rigs:
        raise AnalyzeError(f"{reader.path}: the log carries no rig attachment; give the rig with --rig NAME_OR_TOML")
    name, data = sorted(rigs.items())[0]
    where = f"{reader.path}:{name}"
    from analysis.model.loader import MAX_CONFIG_BYTES

    if len(data) > MAX_CONFIG_BYTES:  # the limits a rig file has (elements, sensors: validate) before any parse
        raise AnalyzeError(
            f"{where}: {len(data)} bytes, over the {MAX_CONFIG_BYTES // 1024} kB limit for a rig; give the rig with --rig"
        )
    try:
        return build_rig(validate(RigConfig, tomllib.loads(data.decode()), where), where)
    except ConfigError as exc:
        raise AnalyzeError(f"{exc}; give the rig with --rig NAME_OR_TOML") from None
    except (ValueError, UnicodeDecodeError) as exc:  # not TOML, or a sensor off the structure
        raise AnalyzeError(f"{where}: the attached rig cannot be used ({exc}); give the rig with --rig NAME_OR_TOML") from None
