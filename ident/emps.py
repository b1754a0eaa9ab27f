"""``coload import emps FILE.mat --out DIR``: the EMPS benchmark's MATLAB file as a recording.

One agent pushing along x: its measured position ``x`` = ``qm`` (y = 0), the applied force
``fx = gtau * vir`` (fy = tau = 0), ``n = 1``, ``edges = []``, ``dt`` the median stamp interval. The
validation file's ``pulses_N`` (an external force the motor force does not contain) is not written:
it is what a prediction has to reveal. Data and their meaning: the EMPS README (docs/diagnose.md).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ident.recording import (
    Recording,
    RecordingError,
    recording_from_arrays,
    write_recording,
)

REQUIRED = ("t", "qm", "vir", "gtau")


def read_emps(path: str | Path) -> Recording:
    """Read an EMPS .mat file into a one-agent recording; raises :class:`RecordingError`."""
    import scipy.io

    path = Path(path)
    try:
        d = scipy.io.loadmat(str(path))
    except (OSError, ValueError, NotImplementedError) as exc:
        raise RecordingError(f"{path}: not a readable MATLAB v5 file: {exc}") from None
    missing = [k for k in REQUIRED if k not in d]
    if missing:
        raise RecordingError(f"{path}: variable(s) {', '.join(missing)} missing "
                             f"(an EMPS file has {', '.join(REQUIRED)})")
    t = np.asarray(d["t"], float).ravel()
    q = np.asarray(d["qm"], float).ravel()
    vir = np.asarray(d["vir"], float).ravel()
    gtau = np.asarray(d["gtau"], float).ravel()
    if gtau.size != 1:
        raise RecordingError(f"{path}: variable gtau: expected a scalar, got {gtau.size} values")
    if not (t.size == q.size == vir.size):
        raise RecordingError(f"{path}: t, qm, vir have different lengths ({t.size}, {q.size}, {vir.size})")
    T = t.size
    wrench = np.zeros((T, 1, 3))
    wrench[:, 0, 0] = gtau[0] * vir
    pos = np.zeros((T, 1, 2))
    pos[:, 0, 0] = q
    dt = float(np.median(np.diff(t))) if T > 1 else None
    return recording_from_arrays(t, wrench, pos=pos, hold="foh", dt=round(dt, 6) if dt else None)


def import_emps(src: str | Path, out: str | Path) -> Path:
    """Read ``src`` and write the recording directory ``out``."""
    return write_recording(out, read_emps(src), extra={"source": f"EMPS benchmark ({Path(src).name})"})
