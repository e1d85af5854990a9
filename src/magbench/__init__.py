"""magbench: a Monte Carlo benchmarking harness for three-axis magnetometer calibration.

Reproduces Papafotis, Nikitas and Sotiriadis, "Magnetic Field Sensors' Calibration: Algorithms'
Overview and Comparison", Sensors 2021, 21, 5288, and goes beyond it.

>>> import magbench
>>> cal = magbench.calibrate(samples, "magical")   # doctest: +SKIP
>>> field = cal.apply(samples)                      # doctest: +SKIP
>>> cal = magbench.calibrate(samples)              # doctest: +SKIP  (the automatic choice)
>>> auto = magbench.calibrate_auto(samples)        # doctest: +SKIP  (with status, verdict)
>>> field = magbench.MagCalibrator("fang").fit(samples).transform(samples)  # doctest: +SKIP
"""

from importlib import import_module

__all__ = ["Calibration", "CalibrationFailed", "MagCalibrator", "calibrate", "calibrate_auto",
           "get_method", "methods", "register"]
__version__ = "0.1.0"

#: Where the public names live. They are imported on first use (PEP 562), so that ``python -m
#: magbench`` starts calibrate's picture process before NumPy, let alone pandas, loads.
#: ``methods`` is the subpackage, which is callable: ``magbench.methods()`` lists the names.
_PUBLIC = {"Calibration": "magbench.core.model", "CalibrationFailed": "magbench.core.model",
           "calibrate_auto": "magbench.pipeline.auto",
           "MagCalibrator": "magbench.methods.estimator",
           "get_method": "magbench.methods.registry", "register": "magbench.methods.registry",
           "methods": None}


def calibrate(samples: object, method: str | None = None, **kwargs: object) -> object:
    """Calibrate magnetometer samples: with ``method``, that method; without, the automatic
    choice of ``python -m magbench calibrate``.

    With ``method``: :func:`magbench.methods.api.calibrate` (keyword options of the method,
    ``angular_rate``/``time`` for the gyro-aided ones, ``raw=True`` for the method's own ``T``
    instead of the safe gauge). Without: :func:`magbench.pipeline.auto.calibrate_auto` (keywords
    ``time``, ``angular_rate``, ``candidates``, ``options``, ``seed``, ...), returning its chosen
    :class:`Calibration`; call ``calibrate_auto`` itself for the status, verdict, intervals and
    choice.

    Returns
    -------
    Calibration
        In the safe gauge (``T`` symmetric positive definite) unless ``raw=True``.

    Raises
    ------
    ValueError
        Bad input (see the two functions).
    CalibrationFailed
        The method could not fit; or, without ``method``, the automatic choice's status is
        FAIL (the reason is the message).
    """
    if method is not None:
        from magbench.methods.api import calibrate as fit

        return fit(samples, method, **kwargs)
    from magbench.core.model import CalibrationFailed
    from magbench.pipeline.auto import calibrate_auto

    auto = calibrate_auto(samples, **kwargs)
    if auto.status == "FAIL" or auto.calibration is None:
        raise CalibrationFailed(f"automatic choice: FAIL: {auto.reason}")
    return auto.calibration


def __getattr__(name: str) -> object:
    if name == "methods":
        return import_module("magbench.methods")
    if name in _PUBLIC:
        value = getattr(import_module(_PUBLIC[name]), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'magbench' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted([*globals(), *_PUBLIC])
