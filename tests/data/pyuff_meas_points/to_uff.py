"""Write ``roving_hammer.uff`` (UFF 58, function type 4: accelerance FRFs) from ``meas_point_{1,2,3}.txt``, with pyuff.

Run from this directory: ``python to_uff.py``. The layout is the one pyuff's own example gives these FRFs
(README.md): response at node 1, hammer at nodes 1, 2, 3 -- one accelerometer and a roving hammer -- direction +X
(1) for both, 0..1000 Hz at 1 Hz. Values are written unchanged (ASCII E20.11: 12 significant digits, more than the
text files' 18 digits need for the comparison in tests/test_public_data.py). Units as the source's example
writes them: acceleration (12) over force (13), m/s^2 / N.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pyuff

HERE = Path(__file__).resolve().parent


def datasets() -> list[dict]:
    out = []
    for i in (1, 2, 3):
        H = np.genfromtxt(HERE / f"meas_point_{i}.txt", dtype=complex)
        out.append(pyuff.prepare_58(
            binary=0, id1=f"H a1/p{i}", id2=f"pyuff data/meas_point_{i}.txt", id3="accelerance", id4="NONE", id5="NONE",
            func_type=4, ver_num=1, load_case_id=0, rsp_ent_name="a1", rsp_node=1, rsp_dir=1, ref_ent_name=f"p{i}",
            ref_node=i, ref_dir=1, ord_data_type=6, num_pts=H.size, abscissa_spacing=1, abscissa_min=0.0,
            abscissa_inc=1.0, abscissa_spec_data_type=18, abscissa_axis_units_lab="Hz", ordinate_spec_data_type=12,
            ordinate_axis_units_lab="m/s^2", orddenom_spec_data_type=13, orddenom_axis_units_lab="N", data=H,
            x=np.arange(H.size, dtype=float)))  # fmt: skip
    return out


if __name__ == "__main__":
    pyuff.UFF(str(HERE / "roving_hammer.uff")).write_sets(datasets(), mode="overwrite")
