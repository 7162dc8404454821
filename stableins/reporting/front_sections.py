"""Sections 1-3 of a certificate: the title block, the method, site and environment, and the inputs."""

from __future__ import annotations

from typing import Any

from reportlab.platypus import Flowable

from stableins.reporting import content, document
from stableins.reporting.context import (
    NOT_RECORDED,
    ReportContext,
    angle_reference,
    degrees,
    entry_text,
    file_name,
    from_poses,
    item_calibrated,
    paragraph,
    period,
    span,
)
from stableins.reporting.document import escape, heading
from stableins.reporting.symbols import MINUS, prose


def title_block(ctx: ReportContext) -> list[Flowable]:
    """Return the title block: the unit, the laboratory and customer, the calibration and the certificate."""
    r = ctx.record
    extra = r.site.extra if r.site else {}

    def field_text(key: str, default: str) -> str:
        return ctx.identification.get(key) or entry_text(r, key) or str(extra.get(key, default))

    rows = [
        ["Technical report of", f"calibration certificate {ctx.report_id}"],
        ["Item calibrated", item_calibrated(r)],
        ["Laboratory", field_text("laboratory", NOT_RECORDED)],
        ["Customer", field_text("customer", NOT_RECORDED)],
        ["Operator", field_text("operator", NOT_RECORDED)],
        ["Location of calibration", field_text("location", NOT_RECORDED if from_poses(r) else "on the system, at its site (section 2)")],
        ["Calibration performed", period(r)],
        ["Procedure", r.calibration.procedure or NOT_RECORDED],
        ["Date of issue", ctx.issued],
        [
            "Software",
            f"stableins {ctx.software_version} (this certificate); calibration by {r.calibration.software or NOT_RECORDED} "
            f"(record schema {r.schema_version})",
        ],
    ]
    out = [
        paragraph("Technical report", "title"),
        paragraph(
            f"Evidence and derivations behind calibration certificate {escape(ctx.report_id)}: the certificate states the results "
            "and conformity; every number here that it states is the same number",
            "subtitle",
        ),
    ]
    if ctx.simulated:
        out.append(
            paragraph(
                f'<font color="{document.VERDICT_COLOURS["fail"].hexval()}"><b>Simulated data</b>: produced by the stableins truth '
                "simulator; the results describe a simulated unit, not a physical one.</font>"
            )
        )
    return out + [
        document.table(rows, [0.24, 0.76], header_rows=0, key_value=True),
        document.spacer(2),
        paragraph(
            "The results relate only to the item calibrated, at the time and under the conditions stated. This report shall not be "
            "reproduced except in full without the written approval of the issuing laboratory.",
            "small",
        ),
    ]


# ---------------------------------------------------------------------- 1 method
def method(ctx: ReportContext) -> list[Flowable]:
    """Return section 1: the procedure and method, the stages run and their settings."""
    r = ctx.record
    out: list[Flowable] = [*heading("1  Procedure and method")]
    out.append(paragraph(_method_text(r)))
    rows: list[list[Any]] = [["Stage", "Procedure", "Data (UTC)", "Sample rate", "Settings"]]
    for s in r.stages_run:
        rate = f"{s.sample_rate:g} Hz" if s.sample_rate else NOT_RECORDED
        settings = prose(content.describe_settings(s.settings), markup_symbols=False)
        rows.append([escape(s.name), escape(s.procedure or NOT_RECORDED), escape(span(s.data_start, s.data_end)), rate, settings])
    out += heading(f"Stages run in this calibration ({escape(r.calibration.id)})", "h2")
    if len(rows) > 1:
        out.append(document.table(rows, [0.13, 0.17, 0.24, 0.09, 0.37], markup=True))
    else:
        out.append(paragraph("None recorded."))
    earlier = [s for s in r.stages if s.calibration != r.calibration.id]
    if earlier:
        out += heading("Stages of earlier calibrations the record carries over", "h2")
        rows = [["Stage", "Procedure", "Data (UTC)", "Calibration"]]
        rows += [[s.name, s.procedure or NOT_RECORDED, span(s.data_start, s.data_end), s.calibration] for s in earlier]
        out.append(document.table(rows, [0.14, 0.22, 0.38, 0.26]))
    if r.calibration.prior is not None:
        prior = r.calibration.prior
        out.append(
            paragraph(
                f"This calibration updates the record in force before it: {escape(file_name(prior.path) if prior.path else 'record')} "
                f"(SHA-256 {escape(prior.sha256[:16])}…, created {escape(prior.created or NOT_RECORDED)}).",
                "small",
            )
        )
    return out


def _method_text(record: Any) -> str:
    """Return what was done: static poses of a triad (``calibrate poses``), or the gimbals' multi-position self-calibration."""
    update = (
        "Each stage is a Bayesian update of the record before it: no uncertainty grows, nothing moves along what its data do not determine."
    )
    if from_poses(record):
        return (
            "Static poses of an accelerometer triad: the triad was held at rest in a number of orientations, recorded by other "
            "means as one continuous log; the static holds were found in the log, and the squared amplitude of the compensated "
            "outputs of each hold was compared with local gravity, |f| = g, whatever the orientation (or, with holds labelled "
            "+x … −z, the six-position test). No gimbal and no orientation reference took part. " + update
        )
    return (
        "Multi-position self-calibration on the system's own gimbals: the platform is turned to a sequence of positions and the "
        "accelerometer outputs are compared with local gravity resolved through the exact gimbal kinematics; at system level the "
        "Earth-rate harmonics of the specific-force error on a static base are separated into accelerometer corrections (after "
        "Wu et al., Sensors 2018, 18, 2888, with the physics re-derived and sign errors corrected). " + update
    )


# ---------------------------------------------------------------------- 2 site
def site_environment(ctx: ReportContext) -> list[Flowable]:
    """Return section 2: the site (latitude, gravity, base attitude) and the environment during the calibration."""
    out: list[Flowable] = [*heading("2  Site and environment")]
    site = ctx.record.site
    if site is None:
        out.append(
            paragraph(
                "Site metadata: not recorded in the calibration record. "
                "Local gravity, the reference of this calibration, is therefore not stated."
            )
        )
    else:
        yaw, pitch, roll = site.base_attitude
        source = ctx.budget.source("gravity") if ctx.budget is not None else None
        rows = [
            ["Quantity", "Value"],
            ["latitude (geodetic)", degrees(site.latitude)],
            ["height (ellipsoidal)", f"{site.height:.1f} m".replace("-", MINUS)],
            ["local gravity g", f"{site.gravity:.7f} m/s²"],
            ["source of g", site.gravity_source],
            ["standard uncertainty of g", f"{source.uncertainty} ({source.origin})" if source is not None else NOT_RECORDED],
            ["base attitude (yaw, pitch, roll)", f"{degrees(yaw)}, {degrees(pitch)}, {degrees(roll)} (site survey)"],
            ["gimbal rotation senses (s1..s4)", ", ".join(f"{s:+d}" for s in site.gimbal_senses)],
            ["reference temperature", f"{site.reference_temperature:.1f} °C"],
        ]
        for s in ctx.record.stages_run:
            rows.append([f"instrument temperature ({s.name})", _temperature(s.environment)])
        if not ctx.record.stages_run:
            rows.append(["instrument temperature", f"{NOT_RECORDED} in the calibration record"])
        out.append(document.table(rows, [0.32, 0.68], key_value=True))
    entries = [(e, "calibration") for e in ctx.record.calibration.entries] + [(e, s.name) for s in ctx.record.stages_run for e in s.entries]
    out += heading("Entries made during the calibration", "h2", room_mm=20)
    if entries:
        rows = [["Entry", "Value", "Asked as", "Stage"]]
        rows += [[e.key.replace("_", " "), e.text(), e.prompt or "—", where] for e, where in entries]
        out.append(document.table(rows, [0.22, 0.22, 0.38, 0.18]))
    else:
        out.append(paragraph("None: no value was entered by a person during this calibration."))
    if site is not None:
        out.append(
            paragraph(
                "Metrological traceability: the reference quantity of this calibration is the local gravity g stated above; scale "
                f"factors are traceable to the SI through it and its source. {angle_reference(ctx.record)} Biases and installation "
                "angles are determined relative to these references.",
                "small",
            )
        )
    return out


def _temperature(environment: Any) -> str:
    temperature = environment.get("temperature") if isinstance(environment, dict) else None
    if isinstance(temperature, dict) and "mean" in temperature:
        text = f"mean {float(temperature['mean']):.2f} °C"
        if "min" in temperature and "max" in temperature:
            text += f", range {float(temperature['min']):.2f} to {float(temperature['max']):.2f} °C"
        return text + " (from the data)"
    return f"{NOT_RECORDED} in the data"


# ---------------------------------------------------------------------- 3 inputs
def inputs(ctx: ReportContext) -> list[Flowable]:
    """Return section 3: every input of the report with its SHA-256 and how it was checked."""
    rows: list[list[Any]] = [["Role", "File", "SHA-256", "Check"]]
    for f in ctx.inputs:
        rows.append([f.role, file_name(f.name), f.sha256, prose(f.check, markup_symbols=False)])
    out: list[Flowable] = [*heading("3  Inputs and their integrity")]
    out.append(
        paragraph(
            "SHA-256 digests of every file this calibration and this report were made from (file names without their folders). "
            "A file whose digest differs is not the file used."
        )
    )
    out.append(document.table([[escape(c) if i != 3 else c for i, c in enumerate(r)] for r in rows], [0.14, 0.25, 0.41, 0.20],
                              mono=(2,), markup=True))  # fmt: skip
    return out
