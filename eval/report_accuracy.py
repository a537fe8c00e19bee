"""The report's accuracy section: the survey control's statement (``eval/accuracy.json``, :mod:`eval.accuracy`) as
tables (the statement, then every point's residuals), a sentence a client can quote, and a plot of the check points'
residuals over the site (:func:`eval.plots.accuracy_residuals_svg`)."""

from __future__ import annotations

import html
import math
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

from core.units import Units
from eval.accuracy import MIN_CHECK_POINTS, NSSDA_H95, NSSDA_V95

Table = tuple[str, list[str], list[list[str]]]


def read_accuracy(path: str | Path | None) -> dict[str, Any] | None:
    """The statement of ``eval/accuracy.json`` (None when the file is absent)."""
    import json

    from core.errors import FormatError

    if path is None or not Path(path).is_file():
        return None
    try:
        data = json.loads(Path(path).read_text(encoding="utf-8"))
    except (ValueError, UnicodeDecodeError) as err:
        raise FormatError(f"the accuracy statement is not valid JSON ({err})", path) from err
    if not isinstance(data, dict):
        raise FormatError("the accuracy statement must hold a JSON object", path)
    return data


def _fmt(u: Units) -> Callable[[Any], str]:
    def length(v: Any) -> str:
        return u.format(float(v), 3) if isinstance(v, (int, float)) and math.isfinite(float(v)) else "n/a"

    return length


def statement_sentence(acc: Mapping[str, Any], u: Units) -> str:
    """One sentence of the statement, in the ASPRS Edition 2 wording."""
    n = int(acc.get("check_points") or 0)
    if n == 0:
        return "No check point was measured: no accuracy can be stated."
    f = _fmt(u)
    h, v = acc.get("class_h_cm"), acc.get("class_v_cm")
    text = (f"This data set was tested to meet ASPRS Positional Accuracy Standards for Digital Geospatial Data, "
            f"Edition 2 (2023), for a {h:g} cm RMSE_H horizontal positional accuracy class and a {v:g} cm RMSE_V "
            f"vertical accuracy class; the actual accuracy found against {n} check points is RMSE_H = "
            f"{f(acc.get('rmse_h'))}, RMSE_V = {f(acc.get('rmse_v'))}, RMSE_3D = {f(acc.get('rmse_3d'))}.")  # fmt: skip
    if acc.get("informal", True):
        text += (f" With fewer than {MIN_CHECK_POINTS} check points the standard's statement is informal: the "
                 "figures describe these points, not a tested product.")  # fmt: skip
    if not acc.get("survey_sigmas_given"):
        text += " The check points' survey accuracy was not given and is taken as exact."
    return text


def accuracy_tables(acc: Mapping[str, Any], u: Units) -> list[Table]:
    """The statement table and the per-point table."""
    f = _fmt(u)
    rows = [
        ["RMSE_x, RMSE_y, RMSE_z", f"{f(acc.get('rmse_x'))}, {f(acc.get('rmse_y'))}, {f(acc.get('rmse_z'))}"],
        ["mean error x, y, z", f"{f(acc.get('mean_dx'))}, {f(acc.get('mean_dy'))}, {f(acc.get('mean_dz'))}"],
        ["RMSE_H, RMSE_V measured", f"{f(acc.get('rmse_h_measured'))}, {f(acc.get('rmse_v_measured'))}"],
        ["check point survey RMSE_H, RMSE_V", f"{f(acc.get('rmse_h_survey'))}, {f(acc.get('rmse_v_survey'))}"],
        ["RMSE_H, RMSE_V (Edition 2, survey folded in)", f"{f(acc.get('rmse_h'))}, {f(acc.get('rmse_v'))}"],
        ["RMSE_3D", f(acc.get("rmse_3d"))],
        [
            f"NSSDA 95 % ({NSSDA_H95}·RMSE_H, {NSSDA_V95}·RMSE_V)",
            f"{f(acc.get('nssda_h95'))}, {f(acc.get('nssda_v95'))}",
        ],
        ["accuracy class met (H, V)", f"{acc.get('class_h_cm')} cm, {acc.get('class_v_cm')} cm"],
        ["check points (control points)", f"{acc.get('check_points')} ({acc.get('control_points')})"],
    ]
    points = []
    for p in acc.get("points") or []:
        points.append([str(p["id"]), str(p["role"]), f(p["dx"]), f(p["dy"]), f(p["dz"]),
                       f(math.sqrt(p["dx"] ** 2 + p["dy"] ** 2 + p["dz"] ** 2)), str(p["marks"]),
                       f"{p['reprojection_px']:.2f}"])  # fmt: skip
    header = ["point", "role", "dx", "dy", "dz", "3D", "marks", "reprojection (px)"]
    return [("Accuracy statement (ASPRS Edition 2)", ["figure", "value"], rows),
            ("Control and check point residuals (model − survey)", header, points)]  # fmt: skip


def accuracy_markdown(acc: Mapping[str, Any] | None, u: Units) -> list[str]:
    if not acc:
        return []
    lines = ["## Survey control: accuracy statement", "", statement_sentence(acc, u), ""]
    for title, header, rows in accuracy_tables(acc, u):
        lines += [f"### {title}", "", "| " + " | ".join(header) + " |", "|" + "|".join("---" for _ in header) + "|"]
        lines += ["| " + " | ".join(r) + " |" for r in rows] + [""]
    return lines


def accuracy_html(
    acc: Mapping[str, Any] | None, u: Units, table: Callable[[list[str], list[list[str]]], str]
) -> list[str]:
    """HTML of the section (``table`` renders a header and rows, as the report's other tables)."""
    from eval.plots import accuracy_residuals_svg

    if not acc:
        return []
    e = html.escape
    parts = ["<h2>Survey control: accuracy statement</h2>", f"<p>{e(statement_sentence(acc, u))}</p>"]
    for title, header, rows in accuracy_tables(acc, u):
        parts += [f"<h3>{e(title)}</h3>", table(header, rows)]
    points = list(acc.get("points") or [])
    if points:
        caption = "horizontal residuals (arrows, exaggerated) and vertical residuals (colour) over the site"
        parts.append(f"<figure>{accuracy_residuals_svg(points, u)}<figcaption>{caption}</figcaption></figure>")
    return parts
