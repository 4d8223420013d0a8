"""Measurement noise models: the variance of each measurement as a function of where it is taken.

A robot maps its states to one *sensing coordinate* per measurement (the x-coordinate of the
point that takes it: a joint of the arm, the point robot itself); a noise model maps those
coordinates ``s`` (M, nz) to the measurement variances (M, nz), the diagonal of ``R``. Gains are
designed with ``R`` at the nominal state and particles simulated with ``R`` at the true state
(METHOD.md 1), so the law is evaluated at many states: every form is vectorised.

Forms, each ONE registered class (``d = s - light_x``):

- ``lightdark_std`` (:class:`LightDarkStd`, paper eq. 14): ``std = eta |d| + sigma_b``;
- ``lightdark_variance`` (:class:`LightDarkVariance`, Platt et al.): ``var = a d^2 + c``;
- ``constant`` (:class:`ConstantNoise`): ``std`` everywhere;
- ``near_beacon`` (:class:`NearBeacon`): ``var = std^2`` where the sensing coordinate ``s`` is at
  above ``radius``, ``near_factor std^2`` within it: for a robot whose sensing coordinate is
  its distance to the nearest beacon (POMDPPlanners' light-dark sensing; benchmarks/peers/pomdpplanners);
- ``callable`` (:class:`CallableNoise`): a user's vectorised function ``s (M, nz) -> var (M, nz)``,
  given from Python (a robot's model), not in a scenario file.

A form names the scenario ``[measurement]`` keys it reads (:attr:`NoiseModel.fields`). The
compiled Monte Carlo engine evaluates a form only if the form names its compiled twin
(:attr:`NoiseModel.compiled`, one of the kernel's forms, with :meth:`NoiseModel.compiled_params`);
otherwise the numpy engine runs. A new form is a new class here or in a user's module, registered
with :func:`register`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable, ClassVar, Mapping

import numpy as np

from firmtool.errors import InputError
from firmtool.util.schema import Field


class NoiseModel:
    """Base class of measurement noise laws (see the module docs)."""

    #: registry name (the scenario's ``measurement.noise``)
    form: ClassVar[str] = ""
    #: the ``[measurement]`` keys this form reads (besides kind, noise and H)
    fields: ClassVar[tuple[Field, ...]] = ()
    #: the compiled engine's name of the same law (see :data:`firmtool.estimation.compiled.NOISE_FORMS`), or None
    compiled: ClassVar[str | None] = None

    @classmethod
    def from_values(cls, values: Mapping[str, Any]) -> "NoiseModel":
        """The model of a scenario's validated ``[measurement]`` values (its :attr:`fields`)."""
        return cls(**{f.name: values[f.name] for f in cls.fields})  # type: ignore[call-arg]

    def variance(self, sensing: np.ndarray) -> np.ndarray:
        """Noise variance per measurement component, same shape as ``sensing``."""
        raise NotImplementedError

    def compiled_params(self) -> dict[str, float]:
        """The constants of the compiled twin (keys light_x, eta, sigma_b, a, c, std; absent = 0)."""
        return {}


@dataclass(frozen=True)
class LightDarkStd(NoiseModel):
    """Paper eq. 14: ``std = eta |s - light_x| + sigma_b``."""

    light_x: float
    eta: float
    sigma_b: float

    form: ClassVar[str] = "lightdark_std"
    compiled: ClassVar[str | None] = "lightdark_std"
    fields: ClassVar[tuple[Field, ...]] = (
        Field("light_x", "number", unit="workspace", doc="x-coordinate of the light line"),
        Field("eta", "number", bound="nonnegative", unit="1", doc="growth of the noise std with the distance to the light"),
        Field("sigma_b", "number", bound="positive", unit="measurement", doc="noise std on the light line"),
    )

    def variance(self, sensing: np.ndarray) -> np.ndarray:
        d = np.asarray(sensing, dtype=float) - self.light_x
        return (self.eta * np.abs(d) + self.sigma_b) ** 2

    def compiled_params(self) -> dict[str, float]:
        return {"light_x": self.light_x, "eta": self.eta, "sigma_b": self.sigma_b}


@dataclass(frozen=True)
class LightDarkVariance(NoiseModel):
    """Platt et al.: ``var = a (s - light_x)^2 + c``."""

    light_x: float
    a: float
    c: float

    form: ClassVar[str] = "lightdark_variance"
    compiled: ClassVar[str | None] = "lightdark_variance"
    fields: ClassVar[tuple[Field, ...]] = (
        Field("light_x", "number", unit="workspace", doc="x-coordinate of the light line"),
        Field("a", "number", bound="nonnegative", doc="growth of the variance with the squared distance to the light"),
        Field("c", "number", bound="positive", doc="variance on the light line"),
    )

    def variance(self, sensing: np.ndarray) -> np.ndarray:
        d = np.asarray(sensing, dtype=float) - self.light_x
        return self.a * d * d + self.c

    def compiled_params(self) -> dict[str, float]:
        return {"light_x": self.light_x, "a": self.a, "c": self.c}


@dataclass(frozen=True)
class ConstantNoise(NoiseModel):
    """The same noise std everywhere."""

    std: float

    form: ClassVar[str] = "constant"
    compiled: ClassVar[str | None] = "constant"
    fields: ClassVar[tuple[Field, ...]] = (
        Field("std", "number", bound="positive", unit="measurement", doc="noise std of every measurement",
              example=0.05),
    )

    def variance(self, sensing: np.ndarray) -> np.ndarray:
        d = np.asarray(sensing, dtype=float)
        return np.full(d.shape, self.std**2)

    def compiled_params(self) -> dict[str, float]:
        return {"std": self.std}


@dataclass(frozen=True)
class NearBeacon(NoiseModel):
    """A step in the distance to the nearest beacon: ``var = near_factor std^2`` if ``s <= radius``,
    else ``std^2``.

    The sensing coordinate ``s`` is the distance the robot reports (a robot whose
    ``sensing_from_points`` gives its distance to the nearest beacon); no compiled twin: the numpy
    engine runs it.

    Attributes
    ----------
    std : float
        Noise std away from every beacon.
    radius : float
        Beacons' reach: below it the variance is ``near_factor std^2``.
    near_factor : float
        Factor of the variance within ``radius`` (POMDPPlanners: 0.5).
    """

    std: float
    radius: float
    near_factor: float

    form: ClassVar[str] = "near_beacon"
    fields: ClassVar[tuple[Field, ...]] = (
        Field("std", "number", bound="positive", unit="measurement", doc="noise std away from every beacon",
              example=1.0),
        Field("radius", "number", bound="positive", unit="workspace",
              doc="reach of a beacon: the variance is near_factor std^2 where the sensing coordinate is within it",
              example=1.5),
        Field("near_factor", "number", bound="positive", unit="1", doc="factor of the variance within radius",
              example=0.5),
    )

    def variance(self, sensing: np.ndarray) -> np.ndarray:
        s = np.asarray(sensing, dtype=float)
        return np.where(s <= self.radius, self.near_factor, 1.0) * self.std**2


@dataclass(frozen=True)
class CallableNoise(NoiseModel):
    """A user's law: ``fn(sensing (M, nz)) -> variance (M, nz)``, vectorised, positive.

    Given from Python (a robot's model), never compiled: the numpy engine runs.
    """

    fn: Callable[[np.ndarray], np.ndarray]

    form: ClassVar[str] = "callable"

    @classmethod
    def from_values(cls, values: Mapping[str, Any]) -> "NoiseModel":
        raise InputError("measurement.noise 'callable' is a Python function given by a robot's model, "
                         "not a scenario form")

    def variance(self, sensing: np.ndarray) -> np.ndarray:
        s = np.asarray(sensing, dtype=float)
        v = np.asarray(self.fn(s), dtype=float)
        if v.shape != s.shape:
            raise InputError(f"noise function: expected variances of shape {s.shape} but found {v.shape}")
        if not np.all(np.isfinite(v)) or np.any(v < 0):
            raise InputError("noise function: expected finite variances >= 0")
        return v


_FORMS: dict[str, type[NoiseModel]] = {}


def register(form: str, cls: type[NoiseModel]) -> type[NoiseModel]:
    """Register a noise form under ``form`` (the scenario's ``measurement.noise``); returns ``cls``."""
    if not (isinstance(cls, type) and issubclass(cls, NoiseModel)):
        raise InputError(f"noise form {form!r}: expected a NoiseModel subclass, found {cls!r}")
    if not form or not all(ch.isalnum() or ch in "_-." for ch in form):
        raise InputError(f"noise form {form!r}: expected a name of letters, digits, '_', '-' or '.'")
    _FORMS[form] = cls
    return cls


def get(form: str) -> type[NoiseModel]:
    """The class registered as ``form`` (InputError naming the known forms if none)."""
    try:
        return _FORMS[form]
    except KeyError:
        raise InputError(f"unknown noise form {form!r}; known: {', '.join(names())}") from None


def names(scenario_only: bool = False) -> tuple[str, ...]:
    """Registered forms (``scenario_only``: those a scenario file can name)."""
    return tuple(n for n, c in _FORMS.items() if not (scenario_only and c is CallableNoise))


def make(form: str, **params: float) -> NoiseModel:
    """A noise model from its form and parameters; parameters the form does not use are ignored
    (the signature of the former ``LightDarkNoise(form, light_x=..., eta=..., ...)``)."""
    cls = get(form)
    return cls(**{f.name: float(params.get(f.name, 0.0)) for f in cls.fields})  # type: ignore[call-arg]


for _cls in (LightDarkStd, LightDarkVariance, ConstantNoise, NearBeacon, CallableNoise):
    register(_cls.form, _cls)
