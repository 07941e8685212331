"""Write ``impacts.uff`` (UFF 58b, function type 1: time histories) from pyFRF's ``data/measurements_{1..5}.npy``.

Usage: ``python to_uff.py PYFRF_DATA_DIR`` (the ``data/`` folder of https://github.com/ladisk/pyFRF at commit
55431fd3c328ddc719232cc34b891291c9982a2e; SOURCE.md). Each ``.npy`` is ``(3, 25600)`` float64: time (s, 25.6 kHz,
1 s), force, response of one hammer hit at the same point.

Made small (SOURCE.md): each record gets 0.1 s of zeros in front (the source's records start 0.86 ms before the
force peak; band-limiting a pulse rings on both sides of it, and in a periodic resampling the ringing before the
pulse would wrap to the record's end and look like a second hit there), then each channel is band-limited to
0-6400 Hz and resampled to 12800 Hz by keeping the lowest lines of its DFT (``scipy.signal.resample``: exact in the
frequency domain, so force and response keep their DFT lines below 6400 Hz, and their ratio -- the FRF -- unchanged
there; the force's ringing stays under 4 % of its peak). The first two hits (of five) are kept, written as float64
(58b, 8 bytes a value; pyuff 2.5 writes float32 58b with a wrong byte count): 450 kB.

Node 1 direction +Z (3) for both the hammer and the accelerometer: a driving-point measurement (the source says no
more). The hits were recorded as separate 1 s records: hit k's starts at 2k s on one time axis (``abscissa_min``),
so a reader that lays records end to end (``gvt import``) keeps them apart, with no data between. Units N and m/s^2
(pyFRF's example treats the response as acceleration).
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pyuff
from scipy.signal import resample

HERE = Path(__file__).resolve().parent
FS_OUT = 12800.0
N_HITS = 2
PRE_S = 0.1  # zeros before each record (see the docstring)
GAP_S = 2.0  # hit k's record starts at k * GAP_S s: separate records on one time axis


def datasets(src: Path) -> list[dict]:
    out = []
    for hit in range(N_HITS):
        t, force, resp = np.load(src / f"measurements_{hit + 1}.npy")
        fs = 1.0 / (t[1] - t[0])
        pad = round(PRE_S * fs)
        force, resp = (np.concatenate([np.zeros(pad), x]) for x in (force, resp))
        n = round(force.size * FS_OUT / fs)
        for name, x, spec, unit in (("force", force, 13, "N"), ("acc", resp, 12, "m/s^2")):
            y = resample(x, n)
            out.append(pyuff.prepare_58(
                binary=1, id1=f"hit {hit} {name} [{unit}]", id2=f"pyFRF data/measurements_{hit + 1}.npy",
                id3=f"{PRE_S:g} s of zeros + record, resampled {fs:g} -> {FS_OUT:g} Hz", id4="NONE",
                id5="NONE", func_type=1, ver_num=hit + 1, load_case_id=0, rsp_ent_name=name, rsp_node=1, rsp_dir=3,
                ref_ent_name="force", ref_node=1, ref_dir=3, ord_data_type=4, num_pts=n, abscissa_spacing=1,
                abscissa_min=GAP_S * hit, abscissa_inc=1.0 / FS_OUT, abscissa_spec_data_type=17,
                abscissa_axis_units_lab="s", ordinate_spec_data_type=spec, ordinate_axis_units_lab=unit,
                orddenom_spec_data_type=0, orddenom_axis_units_lab="NONE", data=y,
                x=GAP_S * hit + np.arange(n) / FS_OUT))  # fmt: skip
    return out


if __name__ == "__main__":
    out = HERE / "impacts.uff"
    out.unlink(missing_ok=True)
    for d in datasets(Path(sys.argv[1])):  # one at a time: pyuff 2.5's write_sets(mode="overwrite") loses a
        pyuff.UFF(str(out)).write_sets(d, mode="add")  # leading binary 58b dataset
