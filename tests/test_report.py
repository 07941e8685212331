"""``gvt report``: one self-contained HTML file, readable without rerun, rendered by a real browser."""

from __future__ import annotations

import base64
import re
import shutil
import subprocess
from pathlib import Path

import pytest

from analysis.model.rigs import open_rig
from daq.session import run_session
from tests.conftest import gvt_command
from tests.test_view import session_config, with_synthetic_confirmation

CHROMIUM = shutil.which("chromium") or ("/usr/bin/chromium" if Path("/usr/bin/chromium").exists() else None)


@pytest.fixture(scope="module")
def logs(tmp_path_factory):
    d = tmp_path_factory.mktemp("report")
    plain = d / "session.mcap"
    res = run_session(session_config(), open_rig("beam_ch4_exp"), plain)
    assert res.lost_samples == 0 and len(res.hits) == 2
    confirmed = d / "confirmed.mcap"
    conf = with_synthetic_confirmation(plain, confirmed)  # SYNTHETIC confirmation message (made-up numbers)
    from daq.report import build_report

    html = d / "report.html"
    summary = build_report(confirmed, html)
    return plain, confirmed, conf, html, summary


def images(doc: str) -> list[bytes]:
    return [base64.b64decode(m) for m in re.findall(r"src='data:image/png;base64,([A-Za-z0-9+/=]+)'", doc)]


def test_report_holds_tables_and_embedded_plots(logs):
    _plain, _confirmed, conf, out, s = logs
    doc = out.read_text()
    assert {"signals", "RQ and modal energies", "RQ-FEP", "wavelet spectrum", "slow flow"} <= set(s.figures)
    pngs = images(doc)
    assert len(pngs) == len(s.figures) and all(p.startswith(b"\x89PNG\r\n\x1a\n") for p in pngs)
    assert not re.search(r"(src|href)=['\"]https?:", doc)  # self-contained: nothing fetched from anywhere
    hits = doc.split("<h2>hits and verdicts</h2>")[1].split("</table>")[0]
    assert hits.count("<tr>") == 1 + 2 and hits.count("accepted") == 2  # header + the two hits
    assert "a14 excluded: clipped" in hits  # the free end clips on the 1583 N hit: that channel out, not the hit
    confs = doc.split("<h2>confirmations (WBEMD + slow flow)</h2>")[1].split("</table>")[0]
    assert "confirmed" in confs and conf["ratio"] in confs and "0.012" in confs
    assert "streams and loss counters" in doc and "internal-resonance events" in doc


def test_gvt_report_says_none_without_confirmations(logs, tmp_path):
    from typer.testing import CliRunner

    from daq.cli import app

    plain = logs[0]
    out = tmp_path / "plain.html"
    r = CliRunner().invoke(app, ["report", str(plain), "--out", str(out)])
    assert r.exit_code == 0, r.output
    assert "none (no /analysis/confirmations in this log)" in out.read_text()
    bad = subprocess.run([*gvt_command(), "report", str(tmp_path / "missing.mcap"), "--out", str(tmp_path / "x.html")],
                         capture_output=True, text=True, timeout=120)  # fmt: skip
    assert bad.returncode == 2 and "file not found" in bad.stderr and len(bad.stderr.splitlines()) == 1


@pytest.mark.browser
@pytest.mark.skipif(CHROMIUM is None, reason="Chromium is not installed (Debian: apt-get install chromium)")
def test_report_renders_in_headless_chromium(logs, tmp_path):
    from matplotlib.image import imread

    out = logs[3]
    shot = tmp_path / "report.png"
    cmd = [CHROMIUM, "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
           "--disable-background-networking", "--disable-component-update", "--disable-sync",
           f"--user-data-dir={tmp_path / 'chromium-profile'}", f"--screenshot={shot}", "--window-size=1280,4000",
           out.as_uri()]  # fmt: skip
    p = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
    assert p.returncode == 0 and shot.exists(), p.stderr[-2000:]
    img = imread(shot)
    assert img.shape[0] == 4000 and img.shape[1] == 1280
    # rendered content, not a blank page: the plots make many distinct colours
    assert img[..., :3].std() > 0.05 and len({tuple(px) for px in (img[::40, ::40, :3] * 255).astype(int).reshape(-1, 3)}) > 20
