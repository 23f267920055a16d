"""Paper 000's interference model I(n, d) (§4.2): epsilon-SVR with an RBF kernel (scikit-learn's libsvm).

``n`` is the group size (fractional for an on-line sample: the mean size over the task), ``d`` the distance from
the object to the delivery point in m, I in wu/s (eq. 3: groupCapacity = idealCapacity - I).

* **Fit.**  Inputs are scaled to [0, 1] (a MinMaxScaler fitted on the samples) and the target standardised, so
  one epsilon (:data:`EPSILON` = 0.05 standardised units) suits any scale: I is of order 0.1-1 wu/s and
  scikit-learn's default epsilon of 0.1 on the raw target would give a flat model (digest §8).  Off-line
  (``search=True``), C and gamma are chosen by 5-fold cross-validated grid search (:data:`GRID_C`,
  :data:`GRID_GAMMA`; a fixed fold split, so a fit is reproducible).  C stops at 100: on standardised targets
  that already fits the samples closely, and libsvm needs ten times longer at C = 1000.
* **On-line** (§4.2.2).  :meth:`InterferenceModel.add` appends a sample, keeps the newest :data:`WINDOW`
  (120) and refits on that window with the chosen C and gamma.  The paper's incremental SVR (Ma et al.,
  Parrella) keeps the exact batch optimum, so a batch refit gives the same model; 120 samples take a few
  milliseconds.  The window applies from the first ``add``: the off-line samples, oldest, leave first.
* **File.**  Versioned JSON (:data:`FORMAT`, :data:`VERSION`): the samples, the hyperparameters, the unit of
  each column and where the samples came from.  Loading refits (never a pickle).  A bad file is one
  :class:`~runtime.errors.InputError` line naming the file and the key.
* :data:`ZERO` is I = 0 (the NI strategies): it predicts 0 and learns nothing.
"""
from __future__ import annotations

import json
import math
import os
from pathlib import Path
from typing import Iterable

import numpy as np

from runtime.errors import InputError
from runtime.jsonfile import read_json

FORMAT = "mrta-interference-model"
VERSION = 1
UNITS = {"n": "robots", "d": "m", "I": "wu/s"}
WINDOW = 120
EPSILON = 0.05
DEFAULT_C, DEFAULT_GAMMA = 10.0, 1.0
GRID_C = (0.1, 1.0, 10.0, 100.0)           # C = 1000 makes a 120-sample refit ~50 ms, not ~4
GRID_GAMMA = (0.1, 0.3, 1.0, 3.0, 10.0, 30.0)
FOLDS = 5
MAX_SAMPLES = 100_000
MAX_FITS = 32             # fitted SVRs kept by (samples, C, gamma, epsilon): a fleet's robots load one model file

Sample = tuple[float, float, float]


def _check_sample(s, where: str) -> Sample:
    """``(n, d, I)`` as floats, or InputError naming ``where``."""
    if not isinstance(s, (list, tuple)) or len(s) != 3:
        raise InputError(f"{where}: expected [n, d, I]")
    if not all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in s):
        raise InputError(f"{where}: expected three numbers [n, d, I]")
    n, d, i = (float(v) for v in s)
    if not all(math.isfinite(v) for v in (n, d, i)):
        raise InputError(f"{where}: expected finite numbers")
    if n <= 0 or d < 0:
        raise InputError(f"{where}: expected n > 0 robots and d >= 0 m, got n={n:g}, d={d:g}")
    return n, d, i


_FITS: dict[tuple, tuple] = {}        # (samples, C, gamma, epsilon) -> (fitted SVR, scale), oldest first


class InterferenceModel:
    """I(n, d) in wu/s (see the module docstring)."""

    def __init__(self, samples: Iterable[Sample] = (), C: float = DEFAULT_C, gamma: float = DEFAULT_GAMMA,
                 epsilon: float = EPSILON, source: str = "", window: int = WINDOW, frozen: bool = False):
        self.samples: list[Sample] = [_check_sample(s, f"samples[{k}]") for k, s in enumerate(samples)]
        self.C, self.gamma, self.epsilon = float(C), float(gamma), float(epsilon)
        self.source = str(source)
        self.window = int(window)
        self.frozen = bool(frozen)
        self._svr = None
        self._scale = (np.zeros(2), np.ones(2), 0.0, 1.0)      # x min, x span, y mean, y sd
        self._refit()

    # ------------------------------------------------------------------ building
    @classmethod
    def from_samples(cls, samples: list[tuple[float, float, float]], search: bool = True,
                     source: str = "") -> "InterferenceModel":
        """A model fitted on ``samples`` ``(n, d m, I wu/s)``; ``search``: choose C and gamma by cross-validated
        grid search (fewer than 2 * :data:`FOLDS` samples keep the defaults)."""
        model = cls(source=source)
        model.fit(samples, search=search)
        return model

    def fit(self, samples, search: bool = True) -> None:
        """Refit on ``samples`` (replacing the ones held); ``search`` as in :meth:`from_samples`."""
        if self.frozen:
            return
        self.samples = [_check_sample(s, f"samples[{k}]") for k, s in enumerate(samples)]
        if search and len(self.samples) >= 2 * FOLDS:
            self.C, self.gamma = self._search()
        self._refit()

    def _arrays(self):
        data = np.asarray(self.samples, dtype=float).reshape(-1, 3)
        x, y = data[:, :2], data[:, 2]
        lo = x.min(axis=0) if len(x) else np.zeros(2)
        span = (x.max(axis=0) - lo) if len(x) else np.ones(2)
        span = np.where(span > 0, span, 1.0)
        mean = float(y.mean()) if len(y) else 0.0
        sd = float(y.std()) if len(y) else 1.0
        sd = sd if sd > 1e-12 else 1.0
        return x, y, (lo, span, mean, sd)

    def _search(self) -> tuple[float, float]:
        from sklearn.model_selection import GridSearchCV, KFold
        from sklearn.svm import SVR

        x, y, (lo, span, mean, sd) = self._arrays()
        grid = GridSearchCV(SVR(kernel="rbf", epsilon=self.epsilon), {"C": list(GRID_C), "gamma": list(GRID_GAMMA)},
                            cv=KFold(FOLDS, shuffle=True, random_state=0), scoring="neg_mean_squared_error")
        grid.fit((x - lo) / span, (y - mean) / sd)
        return float(grid.best_params_["C"]), float(grid.best_params_["gamma"])

    def _refit(self) -> None:
        self._memo = {}
        if not self.samples:
            self._svr = None
            return
        key = (tuple(self.samples), self.C, self.gamma, self.epsilon)
        fitted = _FITS.get(key)
        if fitted is None:
            fitted = self._fit_svr()
            if len(_FITS) >= MAX_FITS:
                del _FITS[next(iter(_FITS))]
            _FITS[key] = fitted
        self._svr, self._scale = fitted

    def _fit_svr(self):
        """(SVR fitted on the samples, scale).  libsvm's fit is deterministic and nothing changes an SVR after it,
        so models holding the same samples and hyperparameters share one (10 robots loading one file: 1 fit, not
        10; 0.1 s each)."""
        from sklearn.svm import SVR

        x, y, scale = self._arrays()
        lo, span, mean, sd = scale
        svr = SVR(kernel="rbf", C=self.C, gamma=self.gamma, epsilon=self.epsilon)
        svr.fit((x - lo) / span, (y - mean) / sd)
        return svr, scale

    # ------------------------------------------------------------------ use
    def predict(self, n: float, d: float) -> float:
        """I in wu/s for ``n`` robots (may be fractional) on an object ``d`` m from the delivery point; 0 with no
        samples."""
        if self._svr is None:
            return 0.0
        key = (float(n), float(d))
        memo = self.__dict__.setdefault("_memo", {})      # leaders ask the same (n, d) again and again: a
        got = memo.get(key)                               # model changes only when refitted, which clears it
        if got is None:
            lo, span, mean, sd = self._scale
            x = (np.array([key]) - lo) / span
            got = memo[key] = float(self._svr.predict(x)[0]) * sd + mean
            if len(memo) > 4096:
                memo.clear()
        return got

    def add(self, n: float, d: float, I: float) -> None:
        """On-line learning: append ``(n, d, I)``, keep the newest :attr:`window` samples, refit with the
        chosen C and gamma.  Does nothing on a frozen model (:data:`ZERO`)."""
        if self.frozen:
            return
        self.samples.append(_check_sample((n, d, I), "sample"))
        del self.samples[:max(0, len(self.samples) - self.window)]
        self._refit()

    def copy(self) -> "InterferenceModel":
        """An independent model with the same samples and hyperparameters (each robot learns on its own)."""
        return InterferenceModel(self.samples, self.C, self.gamma, self.epsilon, self.source, self.window,
                                 self.frozen)

    # ------------------------------------------------------------------ file
    def to_json(self) -> dict:
        return {"format": FORMAT, "version": VERSION, "source": self.source, "units": dict(UNITS),
                "hyperparameters": {"C": self.C, "gamma": self.gamma, "epsilon": self.epsilon},
                "window": self.window, "samples": [list(s) for s in self.samples]}

    def save(self, path) -> None:
        """Write the model file (atomically: a temporary file renamed into place)."""
        path = Path(path)
        tmp = path.with_name(f".{path.name}.tmp{os.getpid()}")
        tmp.write_text(json.dumps(self.to_json(), indent=1) + "\n")
        os.replace(tmp, path)

    @classmethod
    def load(cls, path) -> "InterferenceModel":
        """The model in ``path``, refitted with its hyperparameters; InputError (one line naming the file and the
        key) for anything else than a model file of this format and version."""
        name = str(path) if str(path).isprintable() else repr(str(path))
        data = read_json(path, "interference model file (JSON)")
        try:
            return cls._from_json(data)
        except InputError as exc:
            raise InputError(f"{name}: {exc}") from None

    @classmethod
    def _from_json(cls, data) -> "InterferenceModel":
        if not isinstance(data, dict):
            raise InputError("expected a JSON object")
        if data.get("format") != FORMAT:
            raise InputError(f"format: expected {FORMAT!r}")
        if data.get("version") != VERSION or isinstance(data.get("version"), bool):
            raise InputError(f"version: expected {VERSION}")
        units = data.get("units")
        if units != UNITS:
            raise InputError(f"units: expected {json.dumps(UNITS)}")
        source = data.get("source", "")
        if not isinstance(source, str):
            raise InputError("source: expected a string")
        hyper = data.get("hyperparameters")
        if not isinstance(hyper, dict):
            raise InputError("hyperparameters: expected an object with C, gamma, epsilon")
        values = {}
        for key, lo in (("C", 0.0), ("gamma", 0.0), ("epsilon", None)):
            v = hyper.get(key)
            ok = isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)
            if not ok or (v <= lo if lo is not None else v < 0):
                raise InputError(f"hyperparameters.{key}: expected a finite number "
                                 + ("> 0" if lo is not None else ">= 0"))
            values[key] = float(v)
        window = data.get("window", WINDOW)
        if not isinstance(window, int) or isinstance(window, bool) or not 1 <= window <= MAX_SAMPLES:
            raise InputError(f"window: expected an integer 1..{MAX_SAMPLES}")
        samples = data.get("samples")
        if not isinstance(samples, list) or len(samples) > MAX_SAMPLES:
            raise InputError(f"samples: expected a list of at most {MAX_SAMPLES} [n, d, I]")
        checked = [_check_sample(s, f"samples[{k}]") for k, s in enumerate(samples)]
        return cls(checked, values["C"], values["gamma"], values["epsilon"], source, window)


ZERO = InterferenceModel(source="I = 0 (the NI strategies)", frozen=True)
