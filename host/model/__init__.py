"""The model layer: a tree of rigid bodies (`Model`), built-in models, model files and URDF, the
rotation arithmetic of the package (`rotations`) and inverse kinematics (`ik`).

    >>> from servodyn.model import load_model
    >>> arm = load_model("human_arm")            # built-in, or a .urdf / servodyn .toml file
    >>> from servodyn.model import ik            # inverse kinematics: ik.solve, ik.solve_path
"""

from __future__ import annotations

from pathlib import Path

from .files import BUILTIN_DIR, builtin_models
from .modelfile import load_model_file
from .observer import MomentumObserver
from .tree import INTEGRATORS, Body, Dof, Model, ModelError
from .urdf import load_urdf


def load_model(name_or_path: str | Path, free_root: bool = False) -> Model:
    """A built-in model by name, a URDF file (.urdf) or a servodyn model file (.toml).

    free_root: body 0 floats free (6 dofs; q starts with its origin and unit quaternion) instead
    of being fixed to the base. For a URDF the root link itself becomes that body.
    """
    builtins = builtin_models()
    if str(name_or_path) in builtins:
        model = load_model_file(builtins[str(name_or_path)])
        return model.with_free_root() if free_root else model
    path = Path(name_or_path)
    if not path.exists():
        # a name with a line break or a control character is shown quoted: the error stays one line
        shown = str(name_or_path) if str(name_or_path).isprintable() else repr(str(name_or_path))
        raise ModelError(f"{shown}: no such file, and not a built-in model "
                         f"({', '.join(builtins) or 'none installed'})")
    if path.suffix.lower() not in (".urdf", ".toml"):
        raise ModelError(f"{path}: unknown model format (expected .urdf or .toml)")
    try:
        if path.suffix.lower() == ".urdf":
            return load_urdf(path, free_root=free_root)
        model = load_model_file(path)
        return model.with_free_root() if free_root else model
    except ModelError as err:
        # every error names the file, also those raised where the model is built
        if str(err).startswith(str(path)):
            raise
        raise ModelError(f"{path}: {err}") from None


__all__ = ["INTEGRATORS", "Body", "Dof", "Model", "ModelError", "MomentumObserver", "builtin_models", "load_model"]
