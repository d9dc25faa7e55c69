"""servodyn: closed-form inverse and direct dynamics for a servo-driven humanoid arm.

    >>> import servodyn
    >>> arm = servodyn.load_model("human_arm")
    >>> tau = arm.inverse_dynamics(q, qd, qdd)        # recursive Newton-Euler, in C
    >>> qdd = arm.forward_dynamics(q, qd, tau)        # Armstrong-Green recursion, in C
    >>> q, qd = arm.step(q, qd, tau, 1e-3, "rk4")
"""

from __future__ import annotations

from pathlib import Path

from .model import Body, Dof, Model, ModelError

__version__ = "0.1.0"

MODELS_DIR = Path(__file__).parent / "models"


def builtin_models() -> dict[str, Path]:
    """Built-in model names and their files."""
    return {p.stem: p for p in sorted(MODELS_DIR.glob("*.toml"))}


def load_model(name_or_path: str | Path, free_root: bool = False) -> Model:
    """A built-in model by name, a URDF file (.urdf) or a servodyn model file (.toml).

    free_root: body 0 floats free (6 dofs; q starts with its origin and unit quaternion) instead
    of being fixed to the base. For a URDF the root link itself becomes that body.
    """
    from .modelfile import load_model_file
    from .urdf import load_urdf
    builtins = builtin_models()
    if str(name_or_path) in builtins:
        model = load_model_file(builtins[str(name_or_path)])
        return model.with_free_root() if free_root else model
    path = Path(name_or_path)
    if not path.exists():
        raise ModelError(f"{name_or_path}: no such file, and not a built-in model "
                         f"({', '.join(builtins) or 'none installed'})")
    if path.suffix.lower() == ".urdf":
        return load_urdf(path, free_root=free_root)
    if path.suffix.lower() == ".toml":
        model = load_model_file(path)
        return model.with_free_root() if free_root else model
    raise ModelError(f"{path}: unknown model format (expected .urdf or .toml)")


__all__ = ["Body", "Dof", "Model", "ModelError", "builtin_models", "load_model"]
