"""The metrics of a leaderboard row (:mod:`transient_mi.study.methods`, :mod:`transient_mi.study.methods_fit`): the
columns every row holds and their scoring against the ground truth."""

from __future__ import annotations

#: The metric columns of every row (:func:`recon.metrics.compute_metrics`'s keys).
LEADERBOARD_METRICS = ("chamfer_m", "accuracy_m", "completeness_m", "iou", "depth_mae_m", "visible_chamfer_m",
                       "visible_completeness_m", "visible_iou", "silhouette_iou", "normal_error_deg",
                       "surface_chamfer_m")


def score(rec, gt, seed: int) -> dict:
    """``rec``'s metrics against the ground truth ``gt`` (:func:`recon.metrics.compute_metrics`, surface samples
    drawn with ``seed``); empty without a ground truth."""
    if gt is None:
        return {}
    from recon.metrics import compute_metrics

    return compute_metrics(rec, gt, seed=seed)
