"""Shared building blocks of every schema: strict numbers, vectors and poses.

Units are SI (metres, radians) except where a key says otherwise (``rpy_deg``). A pose maps
coordinates of its child frame into its parent frame (``a_T_b``; docs/conventions.md). Every model
rejects unknown keys.
"""

from __future__ import annotations

import math
from typing import Annotated, Any, Self

import numpy as np
from pydantic import (
    BaseModel,
    BeforeValidator,
    ConfigDict,
    Field,
    ModelWrapValidatorHandler,
    PrivateAttr,
    field_validator,
    model_validator,
)
from pydantic_core import PydanticCustomError

from schemas import rotations as tf

RIGID_TOL = 1e-4
"""A 4x4 ``matrix`` pose is accepted when its rotation is orthonormal to this (max entry of
``R^T R - I``; six printed decimals give ~1e-6) and is then replaced by the nearest rotation."""
EXACT_TOL = 1e-12
QUAT_MIN_NORM = 1e-6
QUAT_NORM_RANGE = (0.5, 2.0)
"""A ``quat`` whose length is outside this range is probably not a quaternion (a warning)."""
RPY_MAX_RAD = 2 * math.pi + 1e-6
MAX_WORLD_M = 20.0
"""Largest plausible world-frame coordinate (m): beyond it a length was given in mm."""
MAX_FLANGE_M = 1.0
"""Largest plausible offset from a flange and mirror side (m)."""


class FieldError(ValueError):
    """A validation error raised by a model-level check that belongs to one of its keys.

    ``loc`` is the key path below the model (``("home",)``, ``("normals", 3)``); the YAML
    error reporter appends it to the model's own path so the message points at that key.
    """

    def __init__(self, loc: tuple[str | int, ...], reason: str) -> None:
        self.loc = loc
        self.reason = reason
        path = ".".join(str(p) for p in loc)
        super().__init__(f"{path}: {reason}" if path else reason)


class StrictModel(BaseModel):
    """Base of every schema model: unknown keys are errors; dumps use the file's key names."""

    model_config = ConfigDict(extra="forbid", serialize_by_alias=True)


def _number(v: object) -> float:
    if isinstance(v, bool) or not isinstance(v, int | float | np.integer | np.floating):
        raise PydanticCustomError("number_type", "expected a number")
    f = float(v)
    if not math.isfinite(f):
        raise PydanticCustomError(
            "finite_number", "expected a finite number, got {value}", {"value": f}
        )
    return f


def _integer(v: object) -> int:
    if isinstance(v, float | np.floating) and float(v).is_integer():
        return int(v)
    if isinstance(v, bool) or not isinstance(v, int | np.integer):
        raise PydanticCustomError("int_type", "expected an integer")
    return int(v)


Num = Annotated[float, BeforeValidator(_number)]
"""A finite number (int or float; bools, strings, NaN and infinities are rejected)."""
PosNum = Annotated[Num, Field(gt=0)]
NonNegNum = Annotated[Num, Field(ge=0)]
Int = Annotated[int, BeforeValidator(_integer)]
"""An integer (an integral float such as ``848.0`` is accepted; bools and strings are not)."""
PosInt = Annotated[Int, Field(ge=1)]
NonNegInt = Annotated[Int, Field(ge=0)]


def exact_length(n: int, noun: str = "numbers") -> BeforeValidator:
    """A check that a list has exactly ``n`` entries ("expected 3 numbers, got 2").

    numpy arrays are accepted and turned into lists.
    """

    def check(v: object) -> object:
        if isinstance(v, np.ndarray):
            v = v.tolist()
        if isinstance(v, list | tuple) and len(v) != n:
            raise PydanticCustomError(
                "wrong_length",
                "expected {n} {noun}, got {got}",
                {"n": n, "noun": noun, "got": len(v)},
            )
        return v

    return BeforeValidator(check)


def _as_list(v: object) -> object:
    return v.tolist() if isinstance(v, np.ndarray) else v


Vec2 = Annotated[list[Num], exact_length(2)]
Vec3 = Annotated[list[Num], exact_length(3)]
Vec4 = Annotated[list[Num], exact_length(4)]
JointVector = Annotated[list[Num], BeforeValidator(_as_list), Field(min_length=1)]
Mat4 = Annotated[list[Vec4], exact_length(4, "rows")]


def unit_rows(rows: list[list[float]], what: str = "normal") -> list[list[float]]:
    """Normalise 3-vectors; a row shorter than 1e-9 is a :class:`FieldError` at its index."""
    out = []
    for i, row in enumerate(rows):
        n = math.sqrt(sum(x * x for x in row))
        if n < 1e-9:
            raise FieldError((i,), f"zero-length {what}")
        out.append([x / n for x in row])
    return out


def rigid_rows(rows: list[list[float]], tol: float = RIGID_TOL) -> list[list[float]]:
    """A 4x4 matrix checked to be rigid to ``tol`` and made exactly rigid.

    The rotation is replaced by the nearest rotation and the last row by ``[0, 0, 0, 1]``
    unless both are already exact (to 1e-12). Raises ``ValueError`` saying how far off the
    matrix is (orthonormality error, determinant, last row) when it is beyond ``tol``.
    """
    T = np.asarray(rows, dtype=float)
    R = T[:3, :3]
    ortho = float(np.max(np.abs(R.T @ R - np.eye(3))))
    if ortho > tol:
        raise ValueError(
            f"rotation part is not orthonormal: max |R^T R - I| = {ortho:.3g} > {tol:g}"
            " (is this a rotation matrix?)"
        )
    det = float(np.linalg.det(R))
    if det < 0:
        raise ValueError(f"rotation part has determinant {det:.3g} (a reflection), expected +1")
    last = float(np.max(np.abs(T[3] - [0.0, 0.0, 0.0, 1.0])))
    if last > tol:
        raise ValueError(f"last row must be [0, 0, 0, 1], got {np.round(T[3], 6).tolist()}")
    if ortho <= EXACT_TOL and last == 0.0:
        return rows
    T[:3, :3] = tf.nearest_rotation(R)
    T[3] = [0.0, 0.0, 0.0, 1.0]
    return T.tolist()


_ROTATION_KEYS = ("rpy", "rpy_deg", "quat", "matrix")


class Pose(StrictModel):
    """A rigid transform ``parent_T_child``: translation ``xyz`` (m) and one rotation form.

    Forms: ``{xyz, rpy}`` (fixed-axis X-Y-Z, rad), ``{xyz, rpy_deg}`` (same, degrees),
    ``{xyz, quat}`` (``[x, y, z, w]``, normalised on load; ``quat_length`` keeps the
    written length) or ``{matrix}`` (4x4 rows, rigid to 1e-4, then made exactly rigid). ``xyz``
    defaults to zeros and the rotation to the identity. An ``rpy`` angle beyond 2 pi is an
    error (degrees given as radians).
    """

    xyz: Vec3 | None = None
    rpy: Vec3 | None = None
    rpy_deg: Vec3 | None = None
    quat: Vec4 | None = None
    matrix_rows: Mat4 | None = Field(default=None, alias="matrix")
    _quat_length: float | None = PrivateAttr(default=None)

    @field_validator("quat")
    @classmethod
    def _normalise_quat(cls, q: list[float] | None) -> list[float] | None:
        if q is None:
            return None
        n = math.sqrt(sum(x * x for x in q))
        if n < QUAT_MIN_NORM:
            raise PydanticCustomError(
                "bad_quaternion", f"quaternion has length {n:.3g}, cannot be normalised"
            )
        return [x / n for x in q]

    @model_validator(mode="wrap")
    @classmethod
    def _keep_quat_length(cls, data: Any, handler: ModelWrapValidatorHandler[Self]) -> Self:
        pose = handler(data)
        raw = data.get("quat") if isinstance(data, dict) else None
        if raw is not None and pose.quat is not None:
            pose._quat_length = math.sqrt(sum(float(x) ** 2 for x in raw))
        return pose

    @property
    def quat_length(self) -> float | None:
        """Length of the ``quat`` as written (before normalisation), None without one."""
        return self._quat_length

    @field_validator("matrix_rows")
    @classmethod
    def _rigid(cls, rows: list[list[float]] | None) -> list[list[float]] | None:
        return None if rows is None else rigid_rows(rows)

    @model_validator(mode="after")
    def _one_rotation(self) -> Self:
        given = [k for k in _ROTATION_KEYS if self._field(k) is not None]
        if len(given) > 1:
            raise FieldError((given[1],), f"give only one of {', '.join(given)}")
        if self.matrix_rows is not None and self.xyz is not None:
            raise FieldError(("xyz",), "not allowed with matrix (put the translation in it)")
        for i, a in enumerate(self.rpy or []):
            if abs(a) > RPY_MAX_RAD:
                raise FieldError(
                    ("rpy", i),
                    f"{a:g} rad is beyond 2 pi: rpy is in radians; for degrees write rpy_deg",
                )
        return self

    def _field(self, key: str) -> Any:
        return self.matrix_rows if key == "matrix" else getattr(self, key)

    def matrix(self) -> tf.Array:
        """The 4x4 homogeneous matrix ``parent_T_child``."""
        if self.matrix_rows is not None:
            return np.asarray(self.matrix_rows, dtype=float)
        if self.rpy is not None:
            R = tf.rpy_to_matrix(self.rpy)
        elif self.rpy_deg is not None:
            R = tf.rpy_to_matrix(np.radians(self.rpy_deg))
        elif self.quat is not None:
            R = tf.quat_to_matrix(self.quat)
        else:
            R = np.eye(3)
        return tf.make_T(R, self.xyz if self.xyz is not None else np.zeros(3))

    @classmethod
    def from_matrix(cls, T: tf.Array | list[list[float]]) -> Pose:
        """``{matrix: T}`` from a 4x4 rigid transform (validated)."""
        rows = np.asarray(T, dtype=float).tolist()
        return cls.model_validate({"matrix": rows})

    def to_dict(self) -> dict[str, Any]:
        """The pose as written in files (only the keys that were given)."""
        return self.model_dump(exclude_none=True)


def check_translation(pose: Pose, key: str, limit_m: float) -> None:
    """A :class:`FieldError` at ``key.xyz`` when a pose's translation exceeds ``limit_m``."""
    p = pose.matrix()[:3, 3]
    dist = float(np.linalg.norm(p))
    if dist > limit_m:
        sub = "matrix" if pose.matrix_rows is not None else "xyz"
        raise FieldError(
            (key, sub),
            f"translation {np.round(p, 4).tolist()} is {dist:g} m from the origin, beyond"
            f" {limit_m:g} m: did you give millimetres? (lengths are in metres)",
        )
