"""Section 7 of a certificate: the evidence that the model fits, per stage, and the system stage's separated combinations."""

from __future__ import annotations

import re
from typing import Any

from reportlab.platypus import Flowable

from stableins.records import CalibrationRecord
from stableins.reporting import content, document, figures, rounding
from stableins.reporting.context import ReportContext, fmt, paragraph
from stableins.reporting.document import escape, heading
from stableins.reporting.symbols import MINUS, prose


# ---------------------------------------------------------------------- 7 evidence
def evidence(ctx: ReportContext) -> list[Flowable]:
    """Return section 7: the residual evidence of every stage's fit and the system stage's separated combinations."""
    from stableins.estimators.result import Stage

    out: list[Flowable] = [*heading("7  Evidence that the model fits", room_mm=50)]
    for note in ctx.evidence_notes:
        out.append(paragraph(prose(note) + ".", "small"))
    if not ctx.stages:
        out.append(
            paragraph(
                "Residual analysis: <b>not performed</b>; the calibration record carries no residual evidence of its stages "
                "and no device-level data file was given."
            )
        )
    else:
        rows: list[list[Any]] = [
            ["Fit", "Stage run", "Obs.", "Rank / param.", "χ²<sub>ν</sub>", "ν", "95\u00a0% interval, noise alone", "Verdict"]
        ]
        colours = {}
        for i, s in enumerate(ctx.stages, start=1):
            low, high = s.chi2_red_interval()
            ok = low <= s.chi2_red <= high
            verdict = "consistent with noise" if ok else ("residuals exceed noise" if s.chi2_red > high else "residuals below noise")
            colours[(i, 7)] = document.VERDICT_COLOURS["pass" if ok else "conditional fail"]
            rows.append(
                [
                    escape(s.stage),
                    escape(s.run or "recomputed"),
                    str(len(s.residuals)),
                    f"{s.rank} / {s.n_parameters}",
                    content.chi2_text(s.chi2_red),
                    str(s.dof),
                    f"{content.chi2_text(low)} to {content.chi2_text(high)}",
                    verdict,
                ]
            )
        widths = [0.12, 0.13, 0.07, 0.12, 0.08, 0.06, 0.20, 0.22]
        out.append(document.table(rows, widths, align_right=(2, 4, 5), cell_colours=colours, markup=True))
        out.append(
            paragraph(
                "χ²<sub>ν</sub> = Σ(r<sub>i</sub>/σ<sub>i</sub>)²/ν with ν = observations − rank; σ<sub>i</sub> is the noise floor of "
                "observation i measured in the data; where the stage models noise correlated between observations (slow bias drift), "
                "χ² is that of the whitened residuals. Values inside the interval mean the model explains the data down to the noise.",
                "small",
            )
        )
        for s in ctx.stages:
            if s.labels and s.unlabelled == 0:
                png, aspect = figures.residuals_by_position(s)
                groups = s.by_position_axis()
                what = (
                    "per axis and of the specific-force magnitude |f| (fine positions)"
                    if "|f|" in groups and len(groups) > 1
                    else "of the specific-force magnitude |f|"
                    if "|f|" in groups
                    else "per axis"
                )
                caption = (
                    f"{ctx.figure_label()} {escape(s.stage.capitalize())} stage: residual of each position {what}, with ±1σ error "
                    "bars; the grey band is the noise floor (±1σ) measured in the data."
                )
            else:
                png, aspect = figures.normalized_residuals(s)
                what = "combined coefficient" if s.stage == Stage.SYSTEM else "observation"
                caption = (
                    f"{ctx.figure_label()} {escape(s.stage.capitalize())} stage: residual of each {what} of the fit divided by its 1σ; "
                    "the grey band is ±1σ, the spread expected from noise alone."
                )
            out.append(document.figure(png, 1.0, aspect, caption))
            out += _notes(ctx, f"Notes of the {s.stage} stage", s.notes)
    out += heading("System-level stage", "h2", room_mm=40)
    out += _system(ctx)
    out += _systematic(ctx)
    return out


#: The system stage's determined combinations (docs/system-calibration.md §4): typeset, and how to turn the
#: stored value [rad] into an engineering unit ("bias": × g in µg; "ppm": × 1e6; "angle": arcsec).
SYSTEM_COMBINATIONS = {
    "b_x - beta_xy*sinL": ("δb<sub>x</sub> − g β<sub>xy</sub> sin L", "bias"),
    "b_y + beta_yx*sinL": ("δb<sub>y</sub> + g β<sub>yx</sub> sin L", "bias"),
    "beta_zy": ("β<sub>zy</sub>", "angle"),
    "beta_zx": ("β<sub>zx</sub>", "angle"),
    "(D_x - D_y)/2": ("½(δSF<sub>x</sub>/SF<sub>x</sub> − δSF<sub>y</sub>/SF<sub>y</sub>)", "ppm"),
    "(beta_xz - beta_yz)/2": ("½(β<sub>xz</sub> − β<sub>yz</sub>)", "angle"),
    "x1 = -(D_x+D_y)/2*cos2L - D_z*sin2L + b_z*sinL": (
        "x<sub>1</sub> = −½(D<sub>x</sub> + D<sub>y</sub>) cos²L − D<sub>z</sub> sin²L + (δb<sub>z</sub>/g) sin L",
        "ppm",
    ),
}
_DETERMINED = re.compile(r"^(?P<name>.+?) = (?P<value>[-+0-9.eE]+) ± (?P<sigma>[0-9.eE+-]+)(?P<not> \(NOT determined by these data\))?$")


def system_combination_rows(record: CalibrationRecord, lines: Any) -> list[tuple[str, float, float, str, bool]]:
    """``(typeset name, correction, 1σ, unit, determined)`` of the system stage's determined lines, in engineering units."""
    from stableins.conventions import ARCSEC, MICRO_G, STANDARD_GRAVITY

    g = record.site.gravity if record.site is not None else STANDARD_GRAVITY
    scale = {"bias": (g / MICRO_G, "µg"), "ppm": (1e6, "ppm"), "angle": (1.0 / ARCSEC, "arcsec")}
    out = []
    for line in lines:
        match = _DETERMINED.match(str(line))
        if match is None:
            continue
        name = match.group("name")
        typeset, kind = SYSTEM_COMBINATIONS.get(name, (prose(name), "angle"))
        factor, unit = scale[kind]
        out.append((typeset, float(match.group("value")) * factor, float(match.group("sigma")) * factor, unit, match.group("not") is None))
    return out


def _system(ctx: ReportContext) -> list[Flowable]:
    from stableins.estimators.result import Stage

    runs = [s for s in ctx.record.stages_run if s.name == Stage.SYSTEM]
    if not runs:
        return [paragraph("<b>Not performed</b>: no system-level stage ran in this calibration.")]
    out: list[Flowable] = []
    for run in runs:
        fit = next((f for f in run.fits if f.get("stage") == Stage.SYSTEM), None)
        chi2 = (
            f"χ²<sub>ν</sub> = {content.chi2_text(float(fit['chi2_red']))} with ν = {fit.get('dof')} (table and figure above). "
            if fit is not None and fit.get("chi2_red") is not None
            else ""
        )
        out.append(
            paragraph(
                "Separation of the combined coefficients (Earth-rate harmonics of the specific-force error, pitch and roll): "
                f"{chi2}What these data determine: the correction each combination asks of the installed calibration (Δ = true − "
                "installed), with its 1σ from these data alone. The record combines it with the installed values and their "
                "uncertainty (a Bayesian update; the results of section 4)."
            )
        )
        rows: list[list[Any]] = [["Combination", "Correction ± 1σ (these data alone)", "Unit", "Determined"]]
        for name, value, sigma, unit, determined in system_combination_rows(ctx.record, run.determined):
            text = f"{rounding.round_to_uncertainty(value, sigma)} ± {rounding.significant_digits(sigma, 2)}" if sigma > 0 else fmt(value)
            rows.append([name, text.replace("-", MINUS), unit, "yes" if determined else "no (short record)"])
        if len(rows) > 1:
            out.append(document.table(rows, [0.50, 0.26, 0.10, 0.14], align_right=(1,), markup=True))
    return out


def _systematic(ctx: ReportContext) -> list[Flowable]:
    """Return the systematic stage's orientations and what they determined (docs/systematic-calibration.md)."""
    from stableins.estimators.result import Stage
    from stableins.estimators.systematic.result import SystematicSettings

    runs = [s for s in ctx.record.stages_run if s.name == Stage.SYSTEMATIC]
    out: list[Flowable] = []
    for run in runs:
        out += heading("Systematic stage: orientations", "h2", room_mm=40)
        out.append(
            paragraph(
                "One Kalman filter over the orientations the platform was indexed to by torquing (the residuals above are its "
                "whitened innovations). Each orientation: the hold, the mean specific force in the platform frame and the angle "
                "of the platform's z axis from the Earth's axis."
            )
        )
        rows: list[list[Any]] = [["Orientation", "Hold [h]", "f<sup>p</sup>/g", "z<sub>p</sub> from the Earth's axis"]]
        orientations = run.settings.orientations if isinstance(run.settings, SystematicSettings) else ()
        for k, hold in enumerate(orientations):
            force = ", ".join(f"{v:+.3f}" for v in hold.specific_force_g).replace("-", MINUS)
            rows.append([str(k + 1), f"{hold.start_h:.2f} – {hold.end_h:.2f}", f"({force})", f"{hold.polar_angle_deg:.1f}°"])
        if len(rows) > 1:
            out.append(document.table(rows, [0.16, 0.24, 0.36, 0.24], align_right=(), markup=True))
        out.append(paragraph("What they determine: the notes of the systematic stage (above); what they do not determine is not moved."))
    return out


def _notes(ctx: ReportContext, title: str, notes: Any) -> list[Flowable]:
    """Return a stage's notes, one per line, in words (:meth:`ReportContext.text`)."""
    notes = [n for n in notes if n]
    if not notes:
        return []
    return [paragraph(f"<b>{escape(title)}</b>", "small"), *(paragraph("• " + ctx.text(n), "note") for n in notes)]
