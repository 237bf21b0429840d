"""Drivers into styles: a scikit-learn-like clusterer over per-driver features.

`StyleClusterer` standardises each feature robustly (median and 1.4826 x MAD, the
standard deviation as a fallback), imputes missing features with the median (0
after standardising), runs k-means (k fixed, or chosen by silhouette or BIC), and
orders the clusters by a defensiveness score: the mean standardised time and gap
feature of the centre (larger TTCs, headways and gaps at the decision = more defensive). Cluster 0 is the most
defensive. Names: k = 3 -> Defensive, Normal, Aggressive; k = 2 -> Defensive,
Aggressive; k > 3 -> Defensive, Normal 1 .. Normal k-2, Aggressive.

Confidence of an assignment: the posterior probability of the assigned cluster
under a spherical Gaussian mixture with the k-means centres, equal weights and
the pooled within-cluster variance per effective dimension (1/k when a driver sits midway between all
centres, near 1 close to its own centre).
"""

from __future__ import annotations

import warnings

import numpy as np
import pandas as pd
from sklearn.cluster import KMeans
from sklearn.metrics import silhouette_score
from sklearn.mixture import GaussianMixture
from threadpoolctl import threadpool_limits

from clustering.behaviour import BOLD_PARAMETERS


def style_names(k: int) -> list[str]:
    """Names of k clusters ordered from most defensive to most aggressive."""
    if k == 1:
        return ["Normal"]
    if k == 2:
        return ["Defensive", "Aggressive"]
    if k == 3:
        return ["Defensive", "Normal", "Aggressive"]
    return ["Defensive"] + [f"Normal {i}" for i in range(1, k - 1)] + ["Aggressive"]


class StyleClusterer:
    """K-means styles over standardised driver features, ordered by defensiveness.

    :param k: number of styles when `choose_k` is None.
    :param choose_k: None, 'silhouette' (highest mean silhouette) or 'bic' (lowest BIC of a
        diagonal Gaussian mixture), over `k_range` (capped at n_samples - 1).
    :param k_range: (smallest, largest) k tried.
    :param n_init: k-means restarts.
    :param random_state: seed of k-means and the mixtures.
    :param bic_variance_floor: variance added to every mixture component (robust z units^2)
        for BIC: with a handful of drivers, a tiny floor lets single drivers become their own
        near-zero-variance cluster and BIC then prefers many clusters (seen on the shipped study:
        k = 5 with 1e-3, k = 3 with 0.01-0.1).
    :param room: the features that measure the room a driver keeps (larger = more defensive), by
        which the styles are ordered and named; None: every feature whose name ends in `_s` or `_m`.
    """

    def __init__(
        self,
        k: int = 3,
        choose_k: str | None = None,
        k_range: tuple[int, int] = (2, 6),
        n_init: int = 50,
        random_state: int = 0,
        bic_variance_floor: float = 0.05,
        room: list[str] | None = None,
    ) -> None:
        self.k = k
        self.room = room
        self.choose_k = choose_k
        self.k_range = k_range
        self.n_init = n_init
        self.random_state = random_state
        self.bic_variance_floor = bic_variance_floor

    # --- helpers -------------------------------------------------------------

    def _standardise(self, X: pd.DataFrame) -> np.ndarray:
        Z = (X.to_numpy(dtype=float) - self.center_) / self.scale_
        return np.where(np.isnan(Z), 0.0, Z)

    def _kmeans(self, Z: np.ndarray, k: int) -> KMeans:
        # one BLAS/OpenMP thread: for these small problems more threads are far slower
        with threadpool_limits(1):
            return KMeans(n_clusters=k, n_init=self.n_init, random_state=self.random_state).fit(Z)

    def _pick_k(self, Z: np.ndarray) -> tuple[int, dict[int, float]]:
        n = len(Z)
        lo, hi = self.k_range
        ks = [k for k in range(max(lo, 2), min(hi, n - 1) + 1)]
        if not ks:
            return min(self.k, n), {}
        scores: dict[int, float] = {}
        for k in ks:
            if self.choose_k == "silhouette":
                labels = self._kmeans(Z, k).labels_
                scores[k] = float(silhouette_score(Z, labels)) if len(set(labels)) > 1 else -1.0
            elif self.choose_k == "bic":
                with threadpool_limits(1):
                    gm = GaussianMixture(
                        k,
                        covariance_type="diag",
                        n_init=5,
                        random_state=self.random_state,
                        reg_covar=self.bic_variance_floor,
                    ).fit(Z)
                scores[k] = float(gm.bic(Z))
            else:
                raise ValueError(f"unknown choose_k {self.choose_k!r}: use 'silhouette' or 'bic'")
        best = (
            max(scores, key=scores.__getitem__)
            if self.choose_k == "silhouette"
            else min(scores, key=scores.__getitem__)
        )
        return best, scores

    # --- API -----------------------------------------------------------------

    def fit(self, features: pd.DataFrame) -> "StyleClusterer":
        """Cluster the rows of `features` (drivers x features; NaN allowed). Returns self."""
        Z = self._fit_scale(features)
        if self.choose_k:
            k, self.k_scores_ = self._pick_k(Z)
        else:
            k, self.k_scores_ = min(self.k, len(Z)), {}
        km = self._kmeans(Z, k)
        return self._place(Z, km.cluster_centers_, km.labels_)

    def fit_partition(self, features: pd.DataFrame, groups: np.ndarray) -> "StyleClusterer":
        """Centres at the means of given groups of the rows of `features` (a partition made
        elsewhere, e.g. by the consensus of several readings) instead of k-means. Returns self."""
        Z = self._fit_scale(features)
        groups = np.asarray(groups)
        ids = sorted(set(groups.tolist()))
        self.k_scores_ = {}
        index = np.array([ids.index(g) for g in groups])
        self._place(Z, np.array([Z[groups == g].mean(axis=0) for g in ids]), index)
        # the given groups stay the labels (not the nearest centre): cluster i is group ids[order_[i]]
        inverse = np.empty(len(ids), dtype=int)
        inverse[self.order_] = np.arange(len(ids))
        self.labels_ = inverse[index]
        return self

    def _fit_scale(self, features: pd.DataFrame) -> np.ndarray:
        """Fit the robust standardisation; the rows standardised."""
        X = features.astype(float)
        if len(X) == 0:
            raise ValueError("no drivers to cluster")
        self.feature_names_in_ = list(X.columns)
        with warnings.catch_warnings():  # a feature nobody has (all NaN) is centred at 0 with scale 1 below
            warnings.simplefilter("ignore", RuntimeWarning)
            self.center_ = np.nanmedian(X.to_numpy(), axis=0)
            mad = 1.4826 * np.nanmedian(np.abs(X.to_numpy() - self.center_), axis=0)
            sd = np.nanstd(X.to_numpy(), axis=0)
        scale = np.where(mad > 1e-9, mad, np.where(sd > 1e-9, sd, 1.0))
        self.scale_ = np.where(np.isnan(scale), 1.0, scale)
        self.center_ = np.where(np.isnan(self.center_), 0.0, self.center_)
        return self._standardise(X)

    def _place(self, Z: np.ndarray, centres: np.ndarray, labels: np.ndarray) -> "StyleClusterer":
        """Order the centres by defensiveness, name them, and fit the posterior's variance."""
        k = len(centres)
        score = self._defensiveness(centres)
        order = np.argsort(-score, kind="stable")  # most defensive first
        self.cluster_centers_ = centres[order]
        self.defensiveness_ = score[order]
        self.order_ = order
        self.k_ = k
        self.names_ = style_names(k)
        # Pooled within-cluster variance per effective dimension, for the posterior. The
        # features are strongly correlated (one line evaluated at several speeds), so the
        # dimension count is the participation ratio of the within-cluster covariance's
        # eigenvalues rather than the number of columns (which would make it overconfident).
        resid = Z - centres[labels]
        eig = np.clip(np.linalg.eigvalsh(resid.T @ resid / max(len(Z), 1)), 0, None)
        p_eff = float(eig.sum() ** 2 / (eig**2).sum()) if (eig**2).sum() > 0 else 1.0
        self.effective_dims_ = p_eff
        inertia = float((resid**2).sum())
        self.sigma2_ = max(inertia / max(Z.shape[0] * p_eff, 1e-9), 1e-6)
        self.labels_, self.confidence_, self.margin_ = self._assign(Z)
        return self

    def order_by(self, score: np.ndarray) -> "StyleClusterer":
        """Re-order (and so re-name) the fitted clusters by `score` per cluster, most defensive
        (largest) first: for styles named by measures other than the features clustered on."""
        order = np.argsort(-np.asarray(score, dtype=float), kind="stable")
        inverse = np.empty_like(order)
        inverse[order] = np.arange(len(order))
        self.cluster_centers_ = self.cluster_centers_[order]
        self.defensiveness_ = np.asarray(score, dtype=float)[order]
        self.labels_ = inverse[self.labels_]
        return self

    def _assign(self, Z: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        d2 = ((Z[:, None, :] - self.cluster_centers_[None, :, :]) ** 2).sum(axis=2)
        labels = d2.argmin(axis=1)
        logp = -d2 / (2 * self.sigma2_)
        logp -= logp.max(axis=1, keepdims=True)
        post = np.exp(logp)
        post /= post.sum(axis=1, keepdims=True)
        conf = post[np.arange(len(Z)), labels]
        d = np.sqrt(np.sort(d2, axis=1))
        margin = 1 - d[:, 0] / d[:, 1] if d.shape[1] > 1 else np.ones(len(Z))
        margin = np.where(np.isfinite(margin), margin, 0.0)
        return labels, conf, margin

    def _defensiveness(self, Z: np.ndarray) -> np.ndarray:
        if self.room is not None:
            room = np.array([c in self.room for c in self.feature_names_in_])
        else:
            room = np.array([c.endswith(("_s", "_m")) for c in self.feature_names_in_])
        cols = room if room.any() else np.ones(len(room), dtype=bool)
        sign = np.array([-1.0 if c in BOLD_PARAMETERS else 1.0 for c in self.feature_names_in_])
        return (Z * sign)[:, cols].mean(axis=1)

    def defensiveness(self, features: pd.DataFrame) -> np.ndarray:
        """Mean standardised time and gap feature of each row (TTCs, headways, gaps in
        seconds or metres: larger = more room kept = more defensive)."""
        return self._defensiveness(self._standardise(features[self.feature_names_in_].astype(float)))

    def transform(self, features: pd.DataFrame) -> np.ndarray:
        """Rows of `features` in the standardised space the clusters live in (NaN imputed as 0)."""
        return self._standardise(features[self.feature_names_in_].astype(float))

    def predict(self, features: pd.DataFrame) -> np.ndarray:
        """Cluster index (0 = most defensive) of each row."""
        return self._assign(self._standardise(features[self.feature_names_in_].astype(float)))[0]

    def predict_confidence(self, features: pd.DataFrame) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(labels, confidence, margin) of each row."""
        return self._assign(self._standardise(features[self.feature_names_in_].astype(float)))

    def distances(self, features: pd.DataFrame) -> np.ndarray:
        """Standardised distance of each row to each centre (n x k)."""
        Z = self._standardise(features[self.feature_names_in_].astype(float))
        return np.sqrt(((Z[:, None, :] - self.cluster_centers_[None, :, :]) ** 2).sum(axis=2))
