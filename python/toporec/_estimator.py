"""ATOL as a scikit-learn estimator, and the TopoRec paper's descriptor."""

from __future__ import annotations

import inspect
import json
import os
from typing import Any, Dict, List

import numpy as np

from . import _toporec

try:  # scikit-learn is optional: with it, the estimators are real sklearn estimators.
    from sklearn.base import BaseEstimator as _Base
    from sklearn.base import TransformerMixin as _Mixin
    from sklearn.exceptions import NotFittedError as _NotFitted
except ImportError:  # pragma: no cover - exercised only without scikit-learn

    class _NotFitted(ValueError, AttributeError):  # type: ignore[no-redef]
        """The estimator is not fitted yet."""

    class _Base:  # type: ignore[no-redef]
        """``get_params`` / ``set_params`` from the constructor's signature, as sklearn's."""

        @classmethod
        def _get_param_names(cls) -> List[str]:
            sig = inspect.signature(cls.__init__)
            return sorted(p for p in sig.parameters if p != "self")

        def get_params(self, deep: bool = True) -> Dict[str, Any]:
            return {k: getattr(self, k) for k in self._get_param_names()}

        def set_params(self, **params: Any) -> "_Base":
            valid = self._get_param_names()
            for k, v in params.items():
                if k not in valid:
                    raise ValueError(f"Invalid parameter {k!r} for estimator {type(self).__name__}")
                setattr(self, k, v)
            return self

        def __repr__(self) -> str:
            args = ", ".join(f"{k}={v!r}" for k, v in self.get_params().items())
            return f"{type(self).__name__}({args})"

    class _Mixin:  # type: ignore[no-redef]
        def fit_transform(self, X: Any, y: Any = None, **fit_params: Any) -> np.ndarray:
            return self.fit(X, y, **fit_params).transform(X)


_CONTRASTS = ("gaussian", "laplacian", "indicator")
_WEIGHTINGS = ("cloud", "iidproba")
_KMEANS = ("minibatch", "lloyd")


def _diagrams(X: Any) -> List[np.ndarray]:
    out = []
    for i, d in enumerate(X):
        a = np.asarray(d, dtype=np.float64)
        if a.size == 0:
            a = np.empty((0, 2))
        if a.ndim != 2 or a.shape[1] != 2:
            raise ValueError(f"diagram {i}: expected a (k, 2) array of (birth, death), got shape {a.shape}")
        out.append(np.ascontiguousarray(a))
    return out


def paper_diagram(diagram: Dict[int, np.ndarray]) -> tuple:
    """The TopoRec paper's choice for one diagram ``{dim: (k, 2) array}``: H2 if it has at
    least 2 finite pairs, else H1 under the same rule, else H0. Returns ``(dim, pairs)``."""
    for dim in (2, 1):
        pairs = np.asarray(diagram.get(dim, np.empty((0, 2))), dtype=np.float64).reshape(-1, 2)
        if np.isfinite(pairs[:, 1]).sum() >= 2:
            return dim, pairs
    return 0, np.asarray(diagram.get(0, np.empty((0, 2))), dtype=np.float64).reshape(-1, 2)


class Atol(_Mixin, _Base):
    """ATOL (Royer et al. 2021): diagrams → fixed-length vectors, a scikit-learn transformer.

    ``fit`` runs k-means (scikit-learn's ``MiniBatchKMeans`` algorithm, or Lloyd) on all
    diagram points with finite coordinates; ``transform`` gives, for each diagram and centre
    ``c_j``, ``Σ_i w_i · C(‖x_i − c_j‖ / σ_j)``: exactly ``gudhi.representations.Atol``'s
    vectors for the same centres and inertias.

    Args:
        b: number of centres (the vector length).
        contrast: ``gaussian``, ``laplacian`` or ``indicator``.
        weighting: ``cloud`` (w = 1) or ``iidproba`` (w = 1/n).
        kmeans: ``minibatch`` or ``lloyd``.
        seed: the k-means seed.

    Attributes (after ``fit``):
        centers_: ``(b, 2)`` centres, sorted by (death, birth); ``inf`` fillers when fewer
            than ``b`` points were seen.
        inertias_: ``(b,)`` scales σ (half the distance to the nearest other centre).
        points_seen_: finite points fitted on.
    """

    def __init__(
        self,
        b: int = 50,
        contrast: str = "laplacian",
        weighting: str = "cloud",
        kmeans: str = "minibatch",
        seed: int = 0,
    ) -> None:
        self.b = b
        self.contrast = contrast
        self.weighting = weighting
        self.kmeans = kmeans
        self.seed = seed

    def _check_params(self) -> None:
        if not isinstance(self.b, (int, np.integer)) or self.b < 1:
            raise ValueError(f"b: expected an integer ≥ 1, got {self.b!r}")
        for name, value, allowed in (
            ("contrast", self.contrast, _CONTRASTS),
            ("weighting", self.weighting, _WEIGHTINGS),
            ("kmeans", self.kmeans, _KMEANS),
        ):
            if value not in allowed:
                raise ValueError(f"{name}: expected one of {', '.join(allowed)}; got {value!r}")

    def fit(self, X: Any, y: Any = None, sample_weight: Any = None) -> "Atol":
        """Fits the centres on the points of the diagrams ``X`` (a list of ``(k, 2)`` arrays)."""
        self._check_params()
        if sample_weight is not None:
            raise ValueError("sample_weight is not supported")
        diagrams = _diagrams(X)
        if not diagrams:
            raise ValueError("Cannot fit Atol on empty target.")
        centers, inertias, seen = _toporec.atol_fit(
            diagrams, int(self.b), self.contrast, self.weighting, self.kmeans, int(self.seed)
        )
        self.centers_, self.inertias_, self.points_seen_ = centers, inertias, int(seen)
        return self

    def _fitted(self) -> None:
        if not hasattr(self, "centers_"):
            raise _NotFitted(f"This {type(self).__name__} instance is not fitted yet; call fit first.")

    def transform(self, X: Any) -> np.ndarray:
        """The ``(n, b)`` ATOL vectors of the diagrams ``X``, computed in parallel."""
        self._fitted()
        self._check_params()
        centers = np.ascontiguousarray(self.centers_, dtype=np.float64)
        inertias = np.ascontiguousarray(self.inertias_, dtype=np.float64)
        return _toporec.atol_transform(_diagrams(X), centers, inertias, self.contrast, self.weighting)

    def __call__(self, diagram: Any) -> np.ndarray:
        """The vector of one diagram (as ``gudhi.representations.Atol``)."""
        return self.transform([diagram])[0]

    def get_feature_names_out(self, input_features: Any = None) -> np.ndarray:
        """``atol_center_0`` .. ``atol_center_{b-1}``."""
        return np.array([f"atol_center_{i}" for i in range(int(self.b))], dtype=object)

    def save(self, path: "os.PathLike[str] | str") -> str:
        """Writes the fitted model as a toporec codebook (the CLI's JSON format, usable with
        ``toporec run``/``vectorize --codebook``, where it is applied with the paper's
        dimension rule); returns the codebook id."""
        self._fitted()
        return _toporec.codebook_save(
            os.fspath(path),
            np.ascontiguousarray(self.centers_, dtype=np.float64),
            np.ascontiguousarray(self.inertias_, dtype=np.float64),
            self.contrast,
            self.weighting,
            self.kmeans,
            int(self.seed),
            int(getattr(self, "points_seen_", 0)),
            True,
        )

    @classmethod
    def load(cls, path: "os.PathLike[str] | str") -> "Atol":
        """A fitted model from a codebook file (one written by :meth:`save` or by the CLI
        with ``dims = "paper"``)."""
        book = json.loads(_toporec.codebook_load(os.fspath(path)))
        parts = book["parts"]
        if len(parts) != 1:
            raise ValueError(
                f"{os.fspath(path)}: a codebook with {len(parts)} parts (dims = {book['dims']}); "
                "Atol.load reads one-part codebooks (dims = \"paper\")"
            )
        kmeans = book["kmeans"]["algorithm"]
        model = cls(b=int(book["b"]), contrast=book["contrast"], weighting=book["weighting"], kmeans=kmeans, seed=int(book["seed"]))
        # Non-finite values are stored as the strings "inf", "-inf", "nan"; float() reads both.
        model.centers_ = np.array([[float(x), float(y)] for x, y in parts[0]["centers"]], dtype=np.float64).reshape(-1, 2)
        model.inertias_ = np.array([float(v) for v in parts[0]["inertias"]], dtype=np.float64)
        model.points_seen_ = int(parts[0].get("points_seen", 0))
        return model


class PaperDescriptor(Atol):
    """The TopoRec paper's descriptor: for each diagram ``{dim: (k, 2) array}`` (what
    :func:`toporec.alpha_persistence` returns), H2 if it has at least 2 finite pairs, else H1
    likewise, else H0; then :class:`Atol` over the chosen pairs. Same parameters and
    attributes as :class:`Atol`; its saved codebook is the CLI's ``dims = "paper"``."""

    def _chosen(self, X: Any) -> List[np.ndarray]:
        out = []
        for i, d in enumerate(X):
            if not isinstance(d, dict):
                raise ValueError(f"diagram {i}: expected a dict {{dim: (k, 2) array}} (alpha_persistence's result)")
            out.append(paper_diagram(d)[1])
        return out

    def fit(self, X: Any, y: Any = None, sample_weight: Any = None) -> "PaperDescriptor":
        """Fits the codebook on each diagram's chosen dimension."""
        super().fit(self._chosen(X), y, sample_weight)
        return self

    def transform(self, X: Any) -> np.ndarray:
        """The ``(n, b)`` descriptors."""
        return super().transform(self._chosen(X))

    def dims_used(self, X: Any) -> np.ndarray:
        """The dimension the rule picks for each diagram."""
        return np.array([paper_diagram(d)[0] for d in X], dtype=np.uint8)
