"""FRFs on the configurations a test lab uses (issue 20): low sample rates, CAN FD, Modbus TCP, a stalling or
restarting device and two devices on one timeline, each through its real transport into a real MCAP log.

Sessions: ``run_session`` with the simulated device behind a pty (serial), on python-can's virtual bus (CAN FD) or
as a Modbus TCP server on 127.0.0.1, with the live FRF lane (daq/lanes/frf.py) on. The rig is ``beam_ch4_exp``
made linear (cubic spring removed) with 1 s records (df = 1 Hz), so a session of three hits lasts 4 s:

* modes 1-2 damped at 3 % instead of 0.5 %: hits 1.25 s apart, the previous hit would otherwise still ring at
  exp(-0.654 * 1.25) = 44 % of mode 1 (measured: coherence 0.96 at the driving point, 0.85 the lowest, at 21 Hz);
  a real test on the 0.5 % beam waits ~10 s between hits;
* every hit on the same sample phase (first hit and period whole numbers of samples at every rate used): the
  simulated device has no anti-alias filter, so at 2048 Hz a 1 ms pulse is two point samples whose spectrum
  depends on where they fall (measured: coherence 0.78-0.84 at 68 Hz with hits at random phases);
* the modes the simulation keeps capped at Nyquist (an ideal anti-alias filter on the responses): with the rig's
  5 kHz cutoff the 1339 Hz mode showed as a peak at 710 Hz (2048 - 1339) in the 2048 Hz session.

Oracles: the rig's modal frequencies (peaks), coherence >= 0.99 at the modes in the band, the count of hits and
``gvt frf`` (``frf_from_log``, an independent path: it reads the records back from the log) on the same log.
Peak tolerance: peaks are bin frequencies (the lane's and gvt frf's alike), so a mode is found within
max(1 %, df / 2) (df / 2 = 0.5 Hz is 2.4 % at mode 1); the parabola-interpolated peak is reported, not held to
1 %: with the window the mode-1 peak is 5.3 % damped and the accelerance's rise pushes it up (+1.3 % measured).
"""

from __future__ import annotations

import re
import time
from pathlib import Path

import numpy as np
import pytest

from analysis.frf import FRFSet
from analysis.model.rig import Rig, load_rig
from analysis.records import FRF_TOPIC
from daq.config.session import SessionConfig
from daq.lanes.frf import default_band, frf_plan, view_curves
from daq.log.reader import LogReader
from daq.session import SessionResult, run_session
from daq.studies.frf import frf_from_log

ROOT = Path(__file__).resolve().parents[1]
RECORD_S = 1.0
PERIOD, FIRST = 1.25, 0.25  # s: whole numbers of samples at 1024 Hz and up
TRIGGER = {"channel": "hammer", "level": 20.0, "pre_trigger": 0.01, "record_length": 0.3}


def lab_rig(tmp: Path, fs: float) -> Rig:
    """Linear ``beam_ch4_exp`` sampled at ``fs``, 1 s records, modes 1-2 at 3 %, simulated modes below Nyquist
    (module docstring); below 2000 Hz a 2 ms hammer tip (the softer tip a lab fits for a 400 Hz band: the session
    refuses a 1 ms pulse shorter than two samples)."""
    src = (ROOT / "configs/rigs/beam_ch4_exp.toml").read_text()
    txt = re.sub(r"\[\[nonlinear_springs\]\].*?(?=\n\[)", "", src, flags=re.S)
    txt = txt.replace("record_length = 2.0", f"record_length = {RECORD_S}")
    txt = txt.replace("zeta = [0.005, 0.005]", "zeta = [0.03, 0.03]")
    txt = txt.replace("modal_cutoff_hz = 5000.0", f"modal_cutoff_hz = {min(5000.0, fs / 2):g}")
    txt = txt.replace("sample_rate = 16384.0", f"sample_rate = {fs:g}")
    if fs < 2000.0:
        txt = txt.replace("pulse_duration = 0.001", "pulse_duration = 0.002")
    assert "[[nonlinear_springs]]" not in txt and "zeta = [0.03, 0.03]" in txt and f"sample_rate = {fs:g}" in txt
    path = tmp / f"beam_lab_{int(fs)}.toml"
    path.write_text(txt)
    return load_rig(path)


Recorded = tuple[Rig, SessionResult, Path, list[str], float]


def record(tmp: Path, fs: float, device: dict | None = None, devices: list | None = None, forces=(300.0, 250.0, 350.0),
           first: float = FIRST, faults: dict | None = None, **top) -> Recorded:  # fmt: skip
    """One session at ``fs`` (serial, all channels, unless ``device``/``devices`` say) with the FRF lane on:
    the rig, result, log, the lane's terminal lines and the wall time."""
    rig = lab_rig(tmp, fs)
    sim = {"forces": list(forces), "period": PERIOD, "first": first, "seed": 3, "sample_rate": fs, **(faults or {})}
    # queue_seconds: a loaded CI machine once left the log short of samples the lane had (gvt frf: 2 of 3 averages)
    spec: dict = {"name": f"lab-{int(fs)}", "rig": str(rig.path), "end_grace_s": 10.0, "trigger": TRIGGER, "queue_seconds": 30.0,
                  "duration": first + len(forces) * PERIOD + 0.05, "analysis": {"enabled": False}, **top}  # fmt: skip
    if devices is not None:
        spec["devices"] = [{**d, "simulate": {**sim, **d.get("simulate", {})}} for d in devices]
    else:
        dev = {"name": "dev0", "driver": "serial", "config": {}, **(device or {})}
        spec["device"] = {**dev, "simulate": {**sim, **dev.get("simulate", {})}}
    cfg = SessionConfig.model_validate(spec)
    out, lines = tmp / "lab.mcap", []
    t0 = time.perf_counter()
    res = run_session(cfg, rig, out, frf_line=lines.append)
    return rig, res, out, lines, time.perf_counter() - t0


def lane_errors(out: Path) -> list[dict]:
    """The FRF lane's ``frf_error`` / ``frf_overrun`` events in the log (an exception or a lane that fell behind)."""
    return [e for e in LogReader(out).json_messages("/daq/events") if e.get("kind") in ("frf_error", "frf_overrun")]


def in_band(rig: Rig, band: float) -> np.ndarray:
    f = rig.modes.frequencies_hz
    return f[(f > 1.0) & (f < band)]


def interpolated_peak(frf: FRFSet, f0: float, half_width_hz: float = 5.0) -> tuple[float, int]:
    """The mode indicator's peak near ``f0``: the largest bin within ``half_width_hz``, refined by a parabola
    through log |sum H| at it and its neighbours; and that bin."""
    mif = np.log(np.abs(frf.H).sum(axis=(0, 1)))
    near = np.flatnonzero(np.abs(frf.freq - f0) <= half_width_hz)
    k = int(near[np.argmax(mif[near])])
    a, b, c = mif[k - 1], mif[k], mif[k + 1]
    shift = 0.5 * (a - c) / (a - 2 * b + c)
    return float(frf.freq[k] + shift * (frf.freq[1] - frf.freq[0])), k


def check_lane_and_log(rig: Rig, res: SessionResult, out: Path, n_hits: int, outputs: tuple[str, ...]) -> dict:
    """The FRF checks every configuration must pass: one lane record per hit, all accepted, the final peaks at the
    in-band modes (df / 2) and coherent (>= 0.99), gvt frf on the log with the same averages and peaks, its
    interpolated peaks within 1 %; returns the measured numbers."""
    fs, df = rig.sample_rate, 1.0 / RECORD_S
    band = default_band(fs)
    recs = res.frf
    assert res.lost_samples == 0 and len(res.hits) == n_hits, (res.events, [(h.t_s, h.verdict) for h in res.hits])
    assert res.writer_overrun_samples == 0  # the log holds every sample the lane saw
    assert not lane_errors(out)
    assert [r["hit"] for r in recs] == [h.hit for h in res.hits] and LogReader(out).json_messages(FRF_TOPIC) == recs
    assert [r["verdict"] for r in recs] == ["accepted"] * n_hits, [r["reason"] for r in recs]
    assert [r["averages"] for r in recs] == list(range(1, n_hits + 1))
    final = recs[-1]
    assert final["band_hz"] == pytest.approx(band) and final["record_s"] == pytest.approx(RECORD_S)
    modes = in_band(rig, band)
    peaks = np.array(final["peaks_hz"])
    err_lane, coh_lane = [], []
    for f in modes:
        j = int(np.argmin(np.abs(peaks - f)))
        err_lane.append((peaks[j] - f) / f)
        assert abs(peaks[j] - f) <= max(0.01 * f, df / 2), (f, peaks)
        coh_lane.append(final["min_coherence"][j])
    assert min(coh_lane) >= 0.99, coh_lane
    run = frf_from_log(out, rig, band_hz=band)
    assert frf_from_log(out, rig).band_hz == band  # gvt frf's default band at this rate is the lane's
    frf = run.frf
    why = [(h["hit"], h["verdict"], h["reason"]) for h in run.hits]
    assert frf is not None and int(frf.n_averages[0]) == final["averages"] == n_hits, why
    assert tuple(frf.outputs) == outputs
    assert [float(f) for f in frf.freq[frf.peaks(6)]] == final["peaks_hz"]  # the same records, the same peaks
    err_log, coh_log = [], []
    for f in modes:  # the bin peaks equal the lane's; their coherence over every response, and the interpolated peak
        fp, k = interpolated_peak(frf, f)
        err_log.append(round((fp - f) / f, 5))
        coh_log.append(round(float(frf.coherence[:, 0, k].min()), 5))
    assert min(coh_log) >= 0.99, coh_log
    return {"modes": modes, "err_lane": err_lane, "err_log": err_log, "coh_lane": coh_lane, "coh_log": coh_log}


ALL = ("a01", "a02", "a03", "a04", "a05", "a06", "a07", "a08", "a09", "a10", "a11", "a12", "a13", "a14")


# --- 1. low sample rates over serial (all 15 channels) and 51.2 kHz -------------------------------------------------
@pytest.mark.parametrize("fs", [1024.0, 2048.0])
def test_low_sample_rates_give_the_modes_in_the_band(tmp_path, fs):
    rig, res, out, lines, wall = record(tmp_path, fs)
    assert rig.sample_rate == fs
    got = check_lane_and_log(rig, res, out, 3, ALL)
    assert len(got["modes"]) == {1024.0: 4, 2048.0: 5}[fs]  # below 400 / 800 Hz: 21 ... 387 / 646 Hz
    assert res.frf[-1]["driving_point"] == "a13" and min(res.frf[-1]["dp_coherence"]) > 0.9  # the 6th peak: no mode
    assert len(lines) == 3 and re.match(r"FRF hit 2 at 2\.75\d s: 3 averages at hammer \(0 refused\)", lines[-1]), lines
    print(f"{fs:g} Hz: wall {wall:.1f} s", got)


def test_51200_hz_over_serial(tmp_path):
    """The top of the range: 51.2 kHz, hammer and two responses (the driving point a13 and a14) over the pty."""
    fs = 51200.0
    rig, res, out, _lines, wall = record(
        tmp_path, fs, device={"simulate": {"channels": ["hammer", "a13", "a14"]}}, forces=(300.0, 250.0)
    )
    got = check_lane_and_log(rig, res, out, 2, ("a13", "a14"))
    print(f"51.2 kHz: wall {wall:.1f} s", got)


# --- 2. CAN FD and Modbus TCP: hammer + a01 + a02, no driving point ---------------------------------------------------
@pytest.mark.parametrize("driver,config", [("can", {"messages": ["GVT_FD3"], "fd": True}),
                                           ("modbus", {"channels": ["hammer", "a01", "a02"], "sample_rate": 16384.0})],
                         ids=["can-fd", "modbus-tcp"])  # fmt: skip
def test_can_and_modbus_with_two_responses_and_no_driving_point(tmp_path, driver, config):
    rig, res, out, lines, wall = record(tmp_path, 16384.0, device={"driver": driver, "config": config})
    got = check_lane_and_log(rig, res, out, 3, ("a01", "a02"))
    final = res.frf[-1]
    assert final["driving_point"] is None and final["dp_mag"] == [] and final["dp_coherence"] == []
    assert "; peaks: 21.0 Hz" in lines[-1]  # the line falls back to the lowest coherence over both responses
    # what the live view draws: the chosen response (the last one), the driving point being absent
    plan = frf_plan(rig, {"dev0": ("hammer", "a01", "a02")}, rig.sample_rate)
    assert plan is not None and plan.driving_point is None and plan.shown == "a02"
    frf = frf_from_log(out, rig).frf
    assert frf is not None
    curves = view_curves(frf, plan, np.hanning(plan.n), 0.0)
    assert list(curves["curves"]) == ["a02"] and curves["driving_point"] is None
    print(f"{driver}: wall {wall:.1f} s", got)


# --- 3. a device that stalls through a hit, one that restarts between hits ---------------------------------------------
def test_a_stall_through_a_hit_loses_nothing_and_every_hit_counts_once(tmp_path):
    """The device stops sending 0.1 s after hit 1 for 0.6 s (data accrues, then comes in a burst): nothing is lost,
    so every hit is averaged, once."""
    rig, res, out, _lines, wall = record(tmp_path, 2048.0, faults={"stall_at_s": FIRST + PERIOD + 0.1, "stall_for_s": 0.6})
    assert res.outcome is not None and res.outcome.exit_code == 0
    got = check_lane_and_log(rig, res, out, 3, ALL)
    assert len({h.index for h in res.hits}) == 3
    print(f"stall: wall {wall:.1f} s", got)


@pytest.fixture(scope="module")
def restarted(tmp_path_factory) -> Recorded:
    """The device restarts 0.5 s after hit 1 (down 0.3 s; the log gets a new segment after a gap). The restarted
    simulated device starts its hit schedule again at its time 0 (hits at 2.55 and 3.80 s in the log: 300 and
    250 N again)."""
    faults = {"restart_at_s": FIRST + PERIOD + 0.5, "restart_down_s": 0.3}
    return record(tmp_path_factory.mktemp("restart"), 2048.0, faults=faults, duration=5.0)


def test_a_restart_inside_a_record_refuses_that_hit_with_the_reason(restarted):
    """Hit 1's gate record (0.3 s) is whole, its 1 s FRF record is not: the lane refuses it as incomplete and
    averages the others, each once; gvt frf on the log refuses the same hit with the same reason."""
    rig, res, out, lines, wall = restarted
    t = [h.t_s for h in res.hits]
    # before the restart the device's clock places the hits (to a sample); the restarted segment is placed after
    # the old one by the gap the host clock implies (drivers/sequence.py: an estimate, the device's clock started
    # again), so hits 2-3 keep their spacing to a sample but sit where the blocks' arrival put them: within the
    # delivery jitter of a loaded 2-core host of 2.55 s = restart at 2.0 s + 0.3 s down + the first hit 0.25 s in
    # (7 ms measured under the suite's two workers and four more busy processes, but the serial twin's gap was
    # 67 ms off beside 4 hogs, tests/test_serial.py): 0.15 s allowed, which still tells a stitched segment (the
    # hit at 2.25 s, 0.3 s off) from a placed one
    assert len(t) == 4 and abs(t[0] - 0.25) < 2 / 2048 and abs(t[1] - 1.5) < 2 / 2048, t
    assert abs(t[3] - t[2] - PERIOD) < 2 / 2048 and abs(t[2] - 2.55) < 0.15, t
    assert res.restarts == 1 and not lane_errors(out)
    recs = res.frf
    hits = [h.hit for h in res.hits]
    assert len(hits) == len(set(hits)) == len({h.index for h in res.hits}) and [r["hit"] for r in recs] == hits
    by_hit = {r["hit"]: r for r in recs}
    assert by_hit[1]["verdict"] == "refused" and by_hit[1]["reason"].startswith("record incomplete"), by_hit[1]
    assert [r["averages"] for r in recs] == [1, 1, 2, 3] and recs[-1]["refused"] == 1
    assert all(r["verdict"] == "accepted" for r in recs if r["hit"] != 1), [(r["hit"], r["reason"]) for r in recs]
    run = frf_from_log(out, rig, band_hz=default_band(rig.sample_rate))
    log = {h["hit"]: h for h in run.hits}
    assert log[0]["verdict"] == "accepted"
    assert log[1]["verdict"] == "refused" and log[1]["reason"].startswith("record incomplete"), log[1]
    print(f"restart: wall {wall:.1f} s", [(r["hit"], r["verdict"], r["reason"][:90]) for r in recs], lines)


def test_gvt_frf_after_a_restart_averages_what_the_lane_averaged(restarted):
    """It refused every hit after the restart while LogReader.read_stream(start, end).gaps listed the stream's gaps
    outside the window (blocks are fetched from 65536 samples before start)."""
    rig, res, out, _lines, _wall = restarted
    run = frf_from_log(out, rig, band_hz=default_band(rig.sample_rate))
    assert [h["verdict"] for h in run.hits] == [r["verdict"] for r in res.frf], [(h["hit"], h["reason"]) for h in run.hits]
    assert run.frf is not None and int(run.frf.n_averages[0]) == res.frf[-1]["averages"] == 3


# --- 4. two devices: the hammer on one, the accelerometers on the other -----------------------------------------------
def test_two_devices_the_lane_builds_frfs_on_the_merged_timeline(tmp_path):
    """sim_two_devices.toml's layout at 2048 Hz: the accelerometer device's clock starts 0.2371 s late; the lane
    takes the responses from its stream at the hit's index less the timeline's fixed offset."""
    acc = list(ALL)
    devices = [{"name": "hammer_daq", "driver": "serial", "simulate": {"channels": ["hammer"]}},
               {"name": "acc_daq", "driver": "serial", "simulate": {"channels": acc, "start_delay": 0.2371}}]  # fmt: skip
    rig, res, out, lines, wall = record(tmp_path, 2048.0, devices=devices, first=1.0, timeline={"settle_s": 0.5},
                                        trigger={**TRIGGER, "driving_point": "a13"})  # fmt: skip
    assert res.timeline and abs(res.timeline["acc_daq"]["applied_samples"] - round(0.2371 * 2048)) <= 2, res.timeline
    recs = res.frf
    assert not lane_errors(out)
    assert len(res.hits) == 3 and [r["verdict"] for r in recs] == ["accepted"] * 3, [r["reason"] for r in recs]
    final = recs[-1]
    assert final["driving_point"] == "a13" and final["averages"] == 3
    peaks = np.array(final["peaks_hz"])
    for f in in_band(rig, default_band(rig.sample_rate)):
        j = int(np.argmin(np.abs(peaks - f)))
        assert abs(peaks[j] - f) <= max(0.01 * f, 0.5 / RECORD_S), (f, peaks)
        assert final["min_coherence"][j] >= 0.99 and final["dp_coherence"][j] >= 0.99, final
    print(f"two devices: wall {wall:.1f} s", final["peaks_hz"], final["min_coherence"], res.timeline, lines)
