"""The C core's sd_model as the host sets it up (servodyn.h's fields, in order, C alignment): read
from the core's bytes into arrays trimmed to the model's bodies and dofs. One reading of that layout
for everything that hands a set-up model to a controller: `servodyn codegen` (C source) and the host
link's load messages (servodyn.loop.link_load)."""

from __future__ import annotations

import numpy as np

from .. import _core


def _sd_model_dtype(max_body: int, max_dof: int) -> np.dtype:
    """The layout of the host's sd_model (double, the host's SD_MAX_* sizes): servodyn.h's
    fields in order, C alignment."""
    B, D, f8, i4 = max_body, max_dof, np.float64, np.int32
    return np.dtype([
        ("nbody", i4), ("ndof", i4), ("free_root", i4), ("gravity", f8, 3),
        ("body_parent", i4, B), ("body_dofnum", i4, B), ("body_dofadr", i4, B), ("body_ball", i4, B),
        ("body_pos", f8, (B, 3)), ("body_rot", f8, (B, 9)), ("dof_rot", f8, (D, 9)),
        ("body_mass", f8, B), ("body_com", f8, (B, 3)), ("body_inertia", f8, (B, 6)),
        ("dof_armature", f8, D),
        ("nq", i4), ("body_qadr", i4, B), ("body_mcom", f8, (B, 3)), ("body_inertia0", f8, (B, 6)),
        ("body_rotT", f8, (B, 9)), ("dof_rotT", f8, (D, 9)), ("body_ident", i4, B),
    ], align=True)


def model_fields(model) -> dict[str, np.ndarray]:
    """The set-up sd_model of `model` as arrays trimmed to its bodies and dofs."""
    raw = model.core.model_bytes()
    dtype = _sd_model_dtype(_core.MAX_BODY, _core.MAX_DOF)
    if dtype.itemsize != len(raw):
        raise RuntimeError(f"sd_model is {len(raw)} bytes, servodyn.model.layout expects "
                           f"{dtype.itemsize}: servodyn.h and layout.py disagree")
    rec = np.frombuffer(raw, dtype=dtype)[0]
    nb, nd = int(rec["nbody"]), int(rec["ndof"])
    out = {}
    for name in dtype.names:
        value = np.array(rec[name])
        if value.ndim and value.shape[0] == _core.MAX_BODY and name.startswith("body_"):
            value = value[:nb]
        elif value.ndim and name.startswith("dof_"):
            value = value[:nd]
        out[name] = value
    return out
