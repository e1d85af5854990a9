"""The method registry: a name for every calibration method, and what the harness needs to know.

A method is a plain function ``fit(samples, **options) -> Calibration`` registered under a
name with :func:`register`. Importing :mod:`magbench.methods.algorithms` registers every module
in it (the one import loop the layers allow, kept inside ``methods/``).
"""

from __future__ import annotations

import functools
import inspect
from collections.abc import Callable
from dataclasses import dataclass

from magbench.core.crb import MODEL_PARAMETERS
from magbench.core.model import Calibration

__all__ = ["DISPLAY_ORDER", "MODEL_PARAMETERS", "Method", "find_method", "get_method",
           "method_label", "methods", "register", "unregister"]

#: Display order of the registered methods: the review's seven in its order of presentation,
#: then the extra methods. Names not listed sort after these, alphabetically.
DISPLAY_ORDER = (
    "twostep", "crassidis", "dorveaux", "vasconcelos", "ali", "wu_shi", "magical",
    "wu_shi_nm", "ellipsoid", "als", "fang", "diagonal", "sphere", "twostep_hi",
    "vasconcelos_printed", "wu_shi_printed", "twostep_no_svd", "crassidis_prior",
)


@dataclass(frozen=True)
class Method:
    """A registered calibration method and what the harness needs to know about it."""

    name: str
    fit: Callable[..., Calibration]
    label: str
    min_samples: int
    family: str = "review"
    randomized: bool = False
    needs_gyro: bool = False
    paper_key: str | None = None
    model: str = "full"
    needs_accel: bool = False

    @property
    def magnetometer_only(self) -> bool:
        """True if the method fits magnetometer samples alone (no gyro, no accelerometer)."""
        return not (self.needs_gyro or self.needs_accel)

    def prepare(self) -> None:
        """Load what the method's first call would load, so that a timed call does not pay
        it: numba and the compiled loops, for a method that has them (nothing otherwise)."""
        from magbench.methods.algorithms._jit import load_for

        load_for(self.fit)

    def option_names(self) -> list[str]:
        """Keyword options the method's ``fit`` accepts (its tuning values)."""
        return list(_keyword_only(self.fit))


@functools.cache
def _keyword_only(fit: Callable[..., Calibration]) -> tuple[str, ...]:
    # Read once per function: every calibrate() call and every trial asks, and
    # inspect.signature costs ~12 us, a tenth of a fast method's whole call at K = 300.
    params = inspect.signature(fit).parameters.values()
    return tuple(p.name for p in params if p.kind is inspect.Parameter.KEYWORD_ONLY)


_REGISTRY: dict[str, Method] = {}


def register(name: str, *, label: str, min_samples: int, family: str = "review",
             randomized: bool = False, needs_gyro: bool = False,
             paper_key: str | None = None, model: str = "full", needs_accel: bool = False,
             ) -> Callable[[Callable[..., Calibration]], Callable[..., Calibration]]:
    """Register ``fit`` under ``name`` (decorator).

    Parameters
    ----------
    name : str
        The name users pass to :func:`calibrate` and to ``algorithms=[...]``.
    label : str
        Name shown in figures and tables.
    min_samples : int
        The smallest K the method accepts: at least its number of identifiable parameters
        plus one, so that the data over-determine the fit. Without a gyro, T is identifiable
        only up to a rotation: a full T and h have 9 (6 + 3: any 9 points lie on some quadric,
        a fit through them is exact whatever the truth), so 10; a sphere ``T = r I`` has 4, so
        5; a bias with a known field magnitude has 3, so 4.
    family : str
        ``"review"`` for the review's seven methods, ``"extra"`` for the others, ``"variant"``
        for a review method run exactly as the review prints it where that print differs from
        the original paper (kept so that both can be reported side by side).
    randomized : bool
        True if ``fit`` takes an ``rng`` option (a ``numpy.random.Generator``).
    needs_gyro : bool
        True if ``fit`` needs ``angular_rate`` and ``time``.
    paper_key : str, optional
        The method's key in the review's Table 2 (reference data), if it is there.
    model : str
        What the method estimates: ``"full"`` (any T and h), ``"diagonal"`` (``T`` diagonal:
        hard iron and one scale per axis), ``"sphere"`` (``T = r I``, hard iron and one scale)
        or ``"bias"`` (``T = I``, hard iron only). The contract tests check
        recovery on data the method's model can represent.
    needs_accel : bool
        True if ``fit`` needs ``acceleration`` (specific force in the IMU's axes, ``(K, 3)``,
        any unit): the alignment methods, which return the rotation to the IMU beside T and h.
    """
    if model not in MODEL_PARAMETERS:
        raise ValueError(f"model must be one of {', '.join(MODEL_PARAMETERS)}, got {model!r}")

    def decorator(fit: Callable[..., Calibration]) -> Callable[..., Calibration]:
        if name in _REGISTRY:
            raise ValueError(f"method {name!r} is registered twice")
        _REGISTRY[name] = Method(name, fit, label, min_samples, family, randomized,
                                 needs_gyro, paper_key, model, needs_accel)
        return fit

    return decorator


def unregister(name: str) -> None:
    """Remove a method (used by tests that register fault-injecting methods)."""
    _REGISTRY.pop(name, None)


def _ensure_loaded() -> None:
    # Importing the package registers every method module it contains.
    import magbench.methods.algorithms  # noqa: F401


def methods() -> list[str]:
    """Names of the registered methods, in display order."""
    _ensure_loaded()
    order = {name: i for i, name in enumerate(DISPLAY_ORDER)}
    return sorted(_REGISTRY, key=lambda n: (order.get(n, len(order)), n))


def get_method(name: str) -> Method:
    """The registered :class:`Method` called ``name``; ``ValueError`` if there is none."""
    _ensure_loaded()
    try:
        return _REGISTRY[name]
    except KeyError:
        raise ValueError(f"unknown method {name!r}; expected one of: "
                         f"{', '.join(methods())}") from None


def find_method(name: str) -> Method | None:
    """The registered :class:`Method` called ``name``, or None (a method of an older run or of
    a plugin not loaded in this process)."""
    _ensure_loaded()
    return _REGISTRY.get(name)


def method_label(name: str) -> str:
    """The name tables and figures show for ``name``: its label, or the name itself when it is
    not registered."""
    spec = find_method(name)
    return name if spec is None else spec.label
