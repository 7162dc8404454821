"""Content builders, one per report section (ISO/IEC 17025:2017 7.8 and the GUM as the checklist).

Each builder takes the :class:`ReportContext` and returns flowables.  A section whose
evidence the record does not carry says so ("not performed" / "not recorded"); no
number is ever made up.  Parameters are printed with their typeset symbols
(:mod:`stableins.reporting.symbols`), values and uncertainties through the one GUM rounding
(:func:`stableins.reporting.rounding.gum`), text from the record through
:func:`stableins.reporting.symbols.prose` (no command-line syntax, no machine paths).
"""

from __future__ import annotations

import math
from typing import Any

from reportlab.platypus import Flowable

from stableins.discovery.diagnose_report import DiagnoseReport
from stableins.reporting import content, document, figures, rounding
from stableins.reporting.certificate_sections import CERTIFICATE_SECTIONS  # noqa: F401 - the certificate, beside its technical report
from stableins.reporting.closing_sections import change, closing, conformity_statement
from stableins.reporting.context import ReportContext
from stableins.reporting.context import file_name as _name
from stableins.reporting.context import fmt as _fmt
from stableins.reporting.context import paragraph as _p
from stableins.reporting.document import escape, heading
from stableins.reporting.evidence_sections import evidence
from stableins.reporting.front_sections import inputs, method, site_environment, title_block
from stableins.reporting.navigation import navigation_section
from stableins.reporting.result_sections import correlations, results, uncertainty
from stableins.reporting.symbols import MINUS, markup, prose


# ---------------------------------------------------------------------- 8 discovery
def discovery(ctx: ReportContext) -> list[Flowable]:
    """Return the model-discovery section: the model in force (the record's discovery history) and the diagnosis.

    The diagnosis (``stableins diagnose --json``) is shown when given.
    """
    out: list[Flowable] = [*heading("8  Model discovery", room_mm=50)]
    history = ctx.record.discovery.to_json() if ctx.record.discovery is not None else None
    if history:
        out += _model_history(ctx, history)
    if ctx.discovery is not None:
        if history:
            out += heading("Diagnosis of the data", "h2")
        out += _diagnosis(ctx, ctx.discovery)
    if not history and ctx.discovery is None:
        out.append(
            _p(
                "<b>Not performed</b>: the calibration record carries no model-discovery history and no diagnosis was given. "
                "The error model is the standard one (Wu et al. 2018 Eq. 6 with the quadratic terms)."
            )
        )
    return out


def _label(text: str, ids: Any = ()) -> str:
    """Return a model label of a discovery step (``+ K3_x``) with typeset names."""
    return prose(text, ids)


def _model_history(ctx: ReportContext, history: dict[str, Any]) -> list[Flowable]:
    """Return the record's ``discovery`` section: every effect tested in the calibration, its verdict, the fit after each step."""
    from stableins.conventions import MICRO_G

    steps = [s for s in history.get("steps", []) if isinstance(s, dict)]
    channels = [str(c) for c in (steps[0].get("channels", []) if steps else [])]
    out: list[Flowable] = [
        *heading("Model in force", "h2"),
        _p(
            f"Effects found by model discovery and estimated with the standard parameters ({escape(str(history.get('stage', '')))} fit "
            f"of the calibration record). Each step adds one effect to the model in force; it stays when the F-test of its "
            f"χ² reduction gives p &lt; α = {float(history.get('alpha', math.nan)):g}, and is otherwise left out of the record. "
            "χ²<sub>ν</sub> is expected within 1 ± 2√(2/ν); the residual RMS is per output axis and for the fine stage's |f|."
        ),
    ]

    def channel(c: str) -> str:
        return "|f|" if c.startswith("|") else f"f<sub>{escape(c.removeprefix('f_'))}</sub>"

    head = ["Step", "Model", "χ²<sub>ν</sub> (ν)"] + [f"RMS {channel(c)}" for c in channels] + ["p", "ΔBIC", "Decision"]
    rows: list[list[Any]] = [head]
    for i, step in enumerate(steps):
        rms = [float(x) / MICRO_G for x in step.get("residual_rms", [])]
        p_value, delta_bic = step.get("p_value"), step.get("delta_bic")
        chi2 = f"{content.chi2_text(float(step.get('chi2_red') or math.nan))} ({step.get('dof', '—')})"
        rows.append(
            [str(i), _label(str(step.get("label", ""))), chi2]
            + [_fmt(x, 3) for x in rms]
            + [
                "—" if p_value is None else f"{float(p_value):.2g}",
                "—" if delta_bic is None else f"{float(delta_bic):+.1f}".replace("-", MINUS),
                escape(str(step.get("decision", ""))),
            ]
        )
    floor = [float(x) / MICRO_G for x in (steps[-1].get("noise_floor", []) if steps else [])]
    rows.append(["", "noise floor", "1"] + [_fmt(x, 3) for x in floor] + ["", "", ""])
    n = len(channels)
    widths = [0.06, 0.17, 0.12] + [0.34 / max(n, 1)] * n + [0.08, 0.08, 0.15]
    out.append(document.table(rows, widths, align_right=tuple(range(2, 5 + n)), markup=True))
    out.append(_p("Residual RMS in µg. Verdicts:", "small"))
    for step in steps[1:]:
        out.append(_p(f"<b>{escape(str(step.get('decision', '')))}</b>: {_label(str(step.get('reason', '')))}", "small"))
    if len(steps) >= 2 and channels:
        png, aspect = figures.model_history(steps)
        caption = (
            f"{ctx.figure_label()} Residual RMS per output channel after each step of the calibration's model; dashed: the noise "
            "floor of the channel of the same colour."
        )
        out.append(document.figure(png, 1.0, aspect, caption))
    return out


def advice_text(advice: str) -> str:
    """Return a candidate's advice as a sentence: "to confirm, repeat ..." rather than "confirm with repeat ..."."""
    advice = advice.strip()
    if advice.startswith("confirm with "):
        advice = "to confirm: " + advice.removeprefix("confirm with ")
    return advice[:1].upper() + advice[1:] if advice else advice


def _estimate_text(estimate: float, sigma: float, unit: str) -> str:
    """Return a candidate's estimate ± 1σ rounded to its σ ("—" when there is none)."""
    if not math.isfinite(estimate):
        return "—"
    if math.isfinite(sigma) and sigma > 0:
        return f"{rounding.round_to_uncertainty(estimate, sigma)} ± {rounding.significant_digits(sigma, 2)} {unit}"
    return f"{_fmt(estimate, 3)} {unit}"


def _diagnosis(ctx: ReportContext, d: DiagnoseReport) -> list[Flowable]:
    """Return the section on the output of ``stableins diagnose --json``: the refit history and the ranked candidates."""
    from stableins.conventions import MICRO_G

    def number(x: float, text: str) -> str:
        return text if math.isfinite(x) else "—"

    out: list[Flowable] = [
        _p(
            f"From {escape(_name(ctx.discovery_source))} (stableins diagnose): {escape(str(d.stage))} stage, "
            f"χ²<sub>ν</sub> = {content.chi2_text(d.chi2_red)} with ν = {d.dof}. Candidates are "
            "ranked by the significance of the residual they explain; ΔBIC &lt; 0 favours adding the effect."
        )
    ]
    rows: list[list[Any]] = [["Candidate", "p-value", "ΔBIC", "Estimate ± 1σ", "Flag", "Advice"]]
    for c in d.candidates[:12]:
        rows.append(
            [
                markup(c.id),
                number(c.p_value, f"{c.p_value:.2g}"),
                number(c.delta_bic, f"{c.delta_bic:.1f}".replace("-", MINUS)),
                _estimate_text(c.estimate, c.sigma, escape(content.printed_unit(c.unit))),
                "yes" if c.flagged else "no",
                prose(advice_text(c.advice)),
            ]
        )
    if len(rows) > 1:
        out.append(document.table(rows, [0.13, 0.09, 0.08, 0.2, 0.07, 0.43], align_right=(1, 2), markup=True))
    else:
        out.append(_p("No candidate effect was tested."))
    steps: list[dict[str, Any]] = []
    for step in d.history:
        rms = [float(x) for x in step.rms]
        floor = [float(x) for x in step.noise_floor]
        if not rms:
            continue
        steps.append(
            {
                "label": step.label,
                "residual_rms": math.sqrt(sum(x * x for x in rms) / len(rms)) / MICRO_G,
                "noise_floor": math.sqrt(sum(x * x for x in floor) / len(floor)) / MICRO_G if floor else None,
                "unit": "µg",
                "chi2_red": step.chi2_red if math.isfinite(step.chi2_red) else None,
                "bic": step.bic if math.isfinite(step.bic) else None,
            }
        )
    if steps:
        out += heading("Refit history", "h2", room_mm=20)
        rows = [["Step", "Model", "Residual RMS [µg]", "Noise floor [µg]", "χ²<sub>ν</sub>", "BIC"]]
        for i, st in enumerate(steps):
            rows.append(
                [
                    str(i),
                    _label(st["label"]),
                    _fmt(st["residual_rms"], 3),
                    _fmt(st["noise_floor"], 3) if st["noise_floor"] is not None else "—",
                    content.chi2_text(float(st["chi2_red"])) if st.get("chi2_red") is not None else "—",
                    f"{float(st['bic']):.1f}".replace("-", MINUS) if st.get("bic") is not None else "—",
                ]
            )
        out.append(document.table(rows, [0.07, 0.33, 0.16, 0.16, 0.12, 0.16], align_right=(2, 3, 4, 5), markup=True))
        if len(steps) >= 2:
            png, aspect = figures.discovery_steps(steps)
            caption = (
                f"{ctx.figure_label()} Residual RMS (RMS over the output axes) after each step of the refit history, with the "
                "noise floor (dashed)."
            )
            out.append(document.figure(png, 1.0, aspect, caption))
        else:
            out.append(
                _p(
                    "One step only: nothing was flagged, so the model was not refitted; the residual RMS of the model in force "
                    f"({_fmt(steps[0]['residual_rms'], 3)} µg) is at or below the noise floor"
                    + (f" ({_fmt(steps[0]['noise_floor'], 3)} µg)." if steps[0]["noise_floor"] is not None else "."),
                    "small",
                )
                if steps[0]["noise_floor"] is None or steps[0]["residual_rms"] <= steps[0]["noise_floor"] * 1.05
                else _p(
                    f"One step only: the model in force leaves a residual RMS of {_fmt(steps[0]['residual_rms'], 3)} µg against a "
                    f"noise floor of {_fmt(steps[0]['noise_floor'], 3)} µg.",
                    "small",
                )
            )
    return out


#: The technical report: everything behind the certificate's numbers, section by section.
TECHNICAL_SECTIONS = (
    title_block,
    method,
    site_environment,
    inputs,
    results,
    uncertainty,
    correlations,
    evidence,
    discovery,
    change,
    conformity_statement,
    navigation_section,
    closing,
)
