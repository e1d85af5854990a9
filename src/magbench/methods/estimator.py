"""A scikit-learn-style estimator: ``MagCalibrator(method=...).fit(X).transform(X)``.

It is a thin layer over :func:`magbench.methods.api.calibrate` for users with scikit-learn's
habits (pipelines, ``get_params``/``set_params``, ``clone``). scikit-learn itself is never
imported here: the estimator protocol is a handful of methods, implemented directly, and
``__sklearn_tags__`` imports scikit-learn only when scikit-learn asks for it. So magbench needs
no scikit-learn, and ``sklearn.utils.estimator_checks`` can still check it (tests/methods).

The fitted correction is held in the safe gauge (:mod:`magbench.core.gauge`): ``transform``
returns ``A (X - b)`` with ``A = (T T^T)^(-1/2)`` symmetric positive definite, the same
corrected vectors a firmware applying ``calibration.json`` computes, never rotated or mirrored.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from magbench.core.model import Calibration, as_samples
from magbench.methods.api import calibrate
from magbench.methods.registry import get_method

__all__ = ["MagCalibrator"]

#: The estimator's default method. At the review's baseline ten methods tie within 10 % of the
#: Cramer-Rao floor at RB >= 99 % (results/report.md, "In short"); Fang's closed-form fit is
#: the fastest of them, needs no random numbers and no iteration cap.
DEFAULT_METHOD = "fang"


class MagCalibrator:
    """Magnetometer calibration as a scikit-learn transformer.

    Parameters
    ----------
    method : str, default "fang"
        A registered method name (``python -m magbench methods`` lists them). Gyro-aided methods
        are refused: a transformer sees only ``X``.
    options : dict, optional
        The method's tuning values, as accepted by :func:`magbench.methods.calibrate`. For a
        randomised method an integer ``rng`` seeds it (default 0), so fits are reproducible.

    Attributes
    ----------
    calibration_ : Calibration
        The fitted model ``y = T m + h`` in the safe gauge (``T`` symmetric positive definite).
    A_ : ndarray, shape (3, 3)
        The correction matrix of ``m = A (y - b)``.
    b_ : ndarray, shape (3,)
        The offset of ``m = A (y - b)``, in the unit of ``X``.
    n_features_in_ : int
        Always 3.

    Examples
    --------
    >>> cal = MagCalibrator(method="ellipsoid").fit(samples)        # doctest: +SKIP
    >>> corrected = cal.transform(samples)  # unit-norm field vectors  # doctest: +SKIP
    """

    def __init__(self, method: str = DEFAULT_METHOD, options: dict | None = None) -> None:
        self.method = method
        self.options = options

    # -- the estimator protocol -----------------------------------------------------------

    def get_params(self, deep: bool = True) -> dict[str, Any]:
        """The constructor's parameters (scikit-learn's ``get_params``)."""
        return {"method": self.method, "options": self.options}

    def set_params(self, **params: Any) -> MagCalibrator:
        """Set constructor parameters by name; ``ValueError`` naming an unknown one."""
        valid = self.get_params()
        for key, value in params.items():
            if key not in valid:
                raise ValueError(f"invalid parameter {key!r} for MagCalibrator; expected one "
                                 f"of: {', '.join(valid)}")
            setattr(self, key, value)
        return self

    def __repr__(self) -> str:
        return f"MagCalibrator(method={self.method!r}, options={self.options!r})"

    def __sklearn_tags__(self):  # returns sklearn.utils.Tags (scikit-learn imported lazily)
        """scikit-learn's tags: a transformer that needs fitting, allows no NaN."""
        from sklearn.utils import Tags, TargetTags, TransformerTags

        return Tags(estimator_type=None, target_tags=TargetTags(required=False),
                    transformer_tags=TransformerTags(), requires_fit=True)

    # -- fitting and correcting -----------------------------------------------------------

    def fit(self, X: object, y: object = None) -> MagCalibrator:
        """Fit the calibration to magnetometer samples.

        Parameters
        ----------
        X : array_like, shape (K, 3)
            Raw magnetometer samples in any unit, one per row.
        y : None
            Ignored (unsupervised); present for the scikit-learn API.

        Returns
        -------
        MagCalibrator
            ``self``, fitted.

        Raises
        ------
        ValueError
            Unknown method or option, a gyro-aided method, or samples a method cannot use
            (wrong shape, NaN, too few, degenerate).
        magbench.core.model.CalibrationFailed
            The method could not produce a finite, invertible estimate.
        """
        spec = get_method(self.method)
        if not spec.magnetometer_only:
            needs = "gyroscope" if spec.needs_gyro else "accelerometer"
            raise ValueError(f"method {self.method!r} needs {needs} data; MagCalibrator "
                             "fits magnetometer samples only (use magbench.methods.calibrate)")
        options = dict(self.options or {})
        if spec.randomized:
            options.setdefault("rng", 0)
        X = _as_array(X)
        cal = calibrate(X, self.method, raw=True, **options)   # made safe once, below
        safe = cal.safe()
        self.calibration_ = safe
        self.A_, self.b_ = safe.correction()
        self.n_features_in_ = 3
        return self

    def transform(self, X: object) -> np.ndarray:
        """Corrected field vectors ``A (X - b)``; unit norm where the model fits.

        Parameters
        ----------
        X : array_like, shape (K, 3) or (3,)

        Returns
        -------
        ndarray of the same shape as ``X``
        """
        cal = self._fitted()
        return cal.apply(_as_array(X, allow_single=True))

    def fit_transform(self, X: object, y: object = None) -> np.ndarray:
        """``fit(X).transform(X)``."""
        return self.fit(X, y).transform(X)

    def inverse_transform(self, X: object) -> np.ndarray:
        """Raw samples ``A^-1 m + b`` that :meth:`transform` maps to ``X``."""
        cal = self._fitted()
        m = _as_array(X, allow_single=True)
        return m @ cal.T.T + cal.h

    def score(self, X: object, y: object = None) -> float:
        """Minus the mean squared field-magnitude error ``(||A (x - b)|| - 1)^2``: higher is
        better, 0 for a perfect fit (review eq. 81, the real-data cost)."""
        m = np.atleast_2d(self.transform(X))
        return -float(np.mean((np.linalg.norm(m, axis=1) - 1.0) ** 2))

    def _fitted(self) -> Calibration:
        cal = getattr(self, "calibration_", None)
        if cal is None:
            # scikit-learn's NotFittedError subclasses ValueError and AttributeError; raising
            # one of its bases keeps scikit-learn out of the import graph.
            raise _NotFitted("this MagCalibrator is not fitted yet; call fit(X) first")
        return cal


class _NotFitted(ValueError, AttributeError):
    """Raised by a transform before fit (as scikit-learn's ``NotFittedError``)."""


def _as_array(X: object, *, allow_single: bool = False) -> np.ndarray:
    """``X`` as a float array of shape (K, 3) (or (3,) where allowed); one-line errors.

    Sparse and complex input get scikit-learn's messages; the rest is the one input check,
    :func:`magbench.core.model.as_samples`."""
    if hasattr(X, "toarray") or type(X).__module__.startswith("scipy.sparse"):
        raise TypeError("sparse input is not supported: magnetometer samples are dense (K, 3)")
    arr = np.asarray(X)
    if np.iscomplexobj(arr):
        raise ValueError("Complex data not supported: magnetometer samples are real (K, 3)")
    arr = arr.astype(float, copy=False)
    if allow_single and arr.shape == (3,):
        if not np.all(np.isfinite(arr)):
            raise ValueError("the sample holds NaN or infinite values")
        return arr
    return as_samples(arr)
