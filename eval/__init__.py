"""Evaluation: distances to ground truth, image metrics, and reports.

Modules (import them directly; this package imports nothing heavy on its own):

- :mod:`eval.c2c` — cloud-to-cloud distances (kd-tree, chunked, one float64 origin), statistics,
  per-class statistics, completeness / precision / recall / F-score.
- :mod:`eval.c2m` — cloud-to-mesh distances (open3d ray casting in a local frame).
- :mod:`eval.registration` — optional point-to-plane ICP before measuring.
- :mod:`eval.geometry` — one product end to end: read, register, measure, write ``c2c_<name>.{ply,las}`` + plots.
- :mod:`eval.image_metrics` — MSE, PSNR, SSIM, MS-SSIM, ΔE (whole image and masked).
- :mod:`eval.lpips` — LPIPS v0.1 / AlexNet in torch, weights from a local file.
- :mod:`eval.render_eval` — render Gaussian sets at held-out views (``fusion.render``) and score them.
- :mod:`eval.metrics_io` — typed per-product results and ``PROJECT/eval/metrics.json``.
- :mod:`eval.report` — ``report/report.{json,md,html}``.
- :mod:`eval.plots` — matplotlib charts (SVG/JPEG), colour-mapped previews, JPEG thumbnails.
"""
