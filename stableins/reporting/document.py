"""Page layout of the calibration report (reportlab platypus).

One typeface everywhere: DejaVu Sans, the font matplotlib ships and draws its figures
with, embedded in the PDF (it has µ, σ, χ, ², ≤ and the true minus sign).  Every page
carries the report id, the unit serial number and "page i of n" (ISO/IEC 17025
7.8.2.1 d); the total page count is known only after layout, so the page furniture is
drawn by :class:`NumberedCanvas` when the document is saved.
"""

from __future__ import annotations

import io
import os
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

from reportlab.lib import colors
from reportlab.lib.enums import TA_LEFT
from reportlab.lib.pagesizes import A4
from reportlab.lib.styles import ParagraphStyle
from reportlab.lib.units import mm
from reportlab.pdfbase import pdfmetrics
from reportlab.pdfbase.ttfonts import TTFont
from reportlab.pdfgen import canvas as canvas_module
from reportlab.platypus import (
    BaseDocTemplate,
    CondPageBreak,
    Flowable,
    Frame,
    PageTemplate,
    Paragraph,
    Spacer,
    Table,
    TableStyle,
)

PAGE_WIDTH, PAGE_HEIGHT = A4
MARGIN = 18 * mm
HEADER = 14 * mm
FOOTER = 14 * mm
#: Width available to text, tables and figures [pt].
TEXT_WIDTH = PAGE_WIDTH - 2 * MARGIN

FONT, FONT_BOLD, FONT_ITALIC, FONT_MONO = "DejaVuSans", "DejaVuSans-Bold", "DejaVuSans-Oblique", "DejaVuSansMono"
BODY_SIZE = 9.0
SMALL_SIZE = 7.5
ACCENT = colors.HexColor("#1f3a5f")
RULE = colors.HexColor("#8a96a3")
SHADE = colors.HexColor("#e8edf3")
ZEBRA = colors.HexColor("#f6f8fa")
VERDICT_COLOURS = {
    "pass": colors.HexColor("#1b7a3a"),
    "fail": colors.HexColor("#b3261e"),
    "conditional pass": colors.HexColor("#8a6d00"),
    "conditional fail": colors.HexColor("#b35c00"),
    "not assessed": colors.HexColor("#5f6b7a"),
}


def register_fonts() -> None:
    """Register DejaVu Sans (regular, bold, oblique, mono) from matplotlib's font directory."""
    if FONT in pdfmetrics.getRegisteredFontNames():
        return
    import matplotlib

    folder = os.path.join(matplotlib.get_data_path(), "fonts", "ttf")
    for name, file in (
        (FONT, "DejaVuSans.ttf"),
        (FONT_BOLD, "DejaVuSans-Bold.ttf"),
        (FONT_ITALIC, "DejaVuSans-Oblique.ttf"),
        (FONT_MONO, "DejaVuSansMono.ttf"),
    ):
        pdfmetrics.registerFont(TTFont(name, os.path.join(folder, file)))
    pdfmetrics.registerFontFamily(FONT, normal=FONT, bold=FONT_BOLD, italic=FONT_ITALIC, boldItalic=FONT_BOLD)


def styles() -> dict[str, ParagraphStyle]:
    """Paragraph styles of the report."""
    register_fonts()
    body = ParagraphStyle("body", fontName=FONT, fontSize=BODY_SIZE, leading=BODY_SIZE * 1.35, alignment=TA_LEFT, spaceAfter=4)
    return {
        "title": ParagraphStyle("title", parent=body, fontName=FONT_BOLD, fontSize=17, leading=21, textColor=ACCENT, spaceAfter=2),
        "subtitle": ParagraphStyle("subtitle", parent=body, fontSize=10, leading=13, textColor=RULE, spaceAfter=10),
        "h1": ParagraphStyle(
            "h1", parent=body, fontName=FONT_BOLD, fontSize=12, leading=15, textColor=ACCENT, spaceBefore=10, spaceAfter=5
        ),
        "h2": ParagraphStyle("h2", parent=body, fontName=FONT_BOLD, fontSize=10, leading=13, spaceBefore=6, spaceAfter=3),
        "body": body,
        "small": ParagraphStyle("small", parent=body, fontSize=SMALL_SIZE, leading=SMALL_SIZE * 1.3, spaceAfter=2),
        "caption": ParagraphStyle(
            "caption", parent=body, fontName=FONT_ITALIC, fontSize=SMALL_SIZE, leading=SMALL_SIZE * 1.3, spaceBefore=2, spaceAfter=8
        ),
        "note": ParagraphStyle(
            "note", parent=body, fontSize=SMALL_SIZE, leading=SMALL_SIZE * 1.55, leftIndent=8, firstLineIndent=-6, spaceAfter=1
        ),
        # 1.4× leading: a subscript (D with g,xy) never touches the row below
        "cell": ParagraphStyle("cell", parent=body, fontSize=SMALL_SIZE + 0.5, leading=(SMALL_SIZE + 0.5) * 1.4, spaceAfter=0),
        "cell_mono": ParagraphStyle(
            "cell_mono", parent=body, fontName=FONT_MONO, fontSize=SMALL_SIZE, leading=SMALL_SIZE * 1.25, spaceAfter=0
        ),
        "head": ParagraphStyle(
            "head", parent=body, fontName=FONT_BOLD, fontSize=SMALL_SIZE + 0.5, leading=(SMALL_SIZE + 0.5) * 1.25, spaceAfter=0
        ),
        "verdict": ParagraphStyle("verdict", parent=body, fontName=FONT_BOLD, fontSize=13, leading=17, spaceBefore=4, spaceAfter=6),
    }


def escape(text: Any) -> str:
    """Text safe for a reportlab Paragraph (which reads a small XML markup)."""
    return str(text).replace("&", "&amp;").replace("<", "&lt;").replace(">", "&gt;")


def table(
    rows: Sequence[Sequence[Any]],
    widths: Sequence[float],
    *,
    header_rows: int = 1,
    align_right: Sequence[int] = (),
    mono: Sequence[int] = (),
    cell_colours: dict[tuple[int, int], Any] | None = None,
    key_value: bool = False,
    markup: bool = False,
) -> Table:
    """Return a ruled table whose cells wrap inside ``widths`` (fractions of the text width if they sum to ≤ 1).

    Strings become Paragraphs (so long text wraps instead of running off the page); with ``markup`` they
    are reportlab markup already (``β<sub>xy</sub>``; the caller escapes), else they are escaped here.
    Flowables are kept as they are.  Header rows repeat on every page the table spans.
    """
    s = styles()
    if sum(widths) <= 1.0 + 1e-9:
        widths = [w * TEXT_WIDTH for w in widths]
    right = ParagraphStyle("cell_right", parent=s["cell"], alignment=2)
    right_head = ParagraphStyle("head_right", parent=s["head"], alignment=2)
    data = []
    for r, row in enumerate(rows):
        out = []
        for c, cell in enumerate(row):
            if isinstance(cell, Flowable):
                out.append(cell)
                continue
            if r < header_rows:
                style = right_head if c in align_right else s["head"]
            else:
                style = s["head"] if key_value and c == 0 else s["cell_mono"] if c in mono else right if c in align_right else s["cell"]
            text = str(cell) if markup else escape(cell)
            if cell_colours and (r, c) in cell_colours:
                text = f'<font color="{cell_colours[(r, c)].hexval()}"><b>{text}</b></font>'
            out.append(Paragraph(text, style))
        data.append(out)
    t = Table(data, colWidths=list(widths), repeatRows=header_rows, hAlign="LEFT")
    t.setStyle(_rules(len(data), header_rows))
    return t


def _rules(n_rows: int, header_rows: int) -> TableStyle:
    """Return the table's rules and shading: accent lines above and below, a shaded header, zebra rows."""
    commands: list[tuple[Any, ...]] = [
        ("VALIGN", (0, 0), (-1, -1), "TOP"),
        ("LEFTPADDING", (0, 0), (-1, -1), 3),
        ("RIGHTPADDING", (0, 0), (-1, -1), 3),
        ("TOPPADDING", (0, 0), (-1, -1), 1.5),
        ("BOTTOMPADDING", (0, 0), (-1, -1), 2),
        ("LINEABOVE", (0, 0), (-1, 0), 0.8, ACCENT),
        ("LINEBELOW", (0, -1), (-1, -1), 0.8, ACCENT),
    ]
    if header_rows:
        commands += [
            ("BACKGROUND", (0, 0), (-1, header_rows - 1), SHADE),
            ("LINEBELOW", (0, header_rows - 1), (-1, header_rows - 1), 0.5, ACCENT),
        ]
    for r in range(header_rows, n_rows):
        if (r - header_rows) % 2 == 1:
            commands.append(("BACKGROUND", (0, r), (-1, r), ZEBRA))
    return TableStyle(commands)


class Figure(Flowable):
    """A figure and its caption that never split, and shrink (down to ``min_scale``) rather than leave a page half empty.

    When the figure at its natural size does not fit in what is left of the frame but fits at ``min_scale`` or
    more, it is drawn as large as the space allows; otherwise it moves to the next page at its natural size.
    """

    def __init__(self, png: bytes, width: float, aspect: float, caption: Paragraph, min_scale: float = 0.8) -> None:
        super().__init__()
        self.png, self.natural_width, self.aspect, self.caption, self.min_scale = png, width, aspect, caption, min_scale
        self.scale = 1.0
        self.hAlign = "CENTER"

    def wrap(self, available_width: float, available_height: float) -> tuple[float, float]:
        """Fit the figure and its caption into the space left, shrinking it down to ``min_scale``."""
        self.width = available_width
        _, self.caption_height = self.caption.wrap(available_width, available_height)
        self.caption_height += self.caption.getSpaceBefore() + self.caption.getSpaceAfter()
        natural = self.natural_width * self.aspect
        room = available_height - self.caption_height
        self.scale = 1.0 if natural <= room or room < self.min_scale * natural else max(room / natural, self.min_scale)
        self.height = natural * self.scale + self.caption_height
        return self.width, self.height

    def split(self, available_width: float, available_height: float) -> list[Flowable]:
        """Refuse to split: a figure moves whole to the next frame."""
        return []

    def draw(self) -> None:
        """Draw the image centred, with its caption below."""
        from reportlab.lib.utils import ImageReader

        width = self.natural_width * self.scale
        height = width * self.aspect
        x = (self.width - width) / 2.0
        self.canv.drawImage(ImageReader(io.BytesIO(self.png)), x, self.caption_height, width, height)
        self.caption.drawOn(self.canv, 0, self.caption.getSpaceAfter())


def figure(png: bytes, width_fraction: float, aspect: float, caption: str, min_scale: float = 0.8) -> Figure:
    """Return a high-dpi PNG figure at a fraction of the text width, with its caption (:class:`Figure`).

    ``aspect`` is height / width of the figure as drawn by matplotlib.
    """
    s = styles()
    return Figure(png, width_fraction * TEXT_WIDTH, aspect, Paragraph(caption, s["caption"]), min_scale)


class NumberedCanvas(canvas_module.Canvas):
    """Canvas that draws the page furniture with "page i of n" once the total is known."""

    furniture: dict[str, str] = {}

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self._pages: list[dict[str, Any]] = []

    def showPage(self) -> None:  # noqa: N802 (reportlab API)
        """Keep the page's state: the furniture (page x of n) is drawn when the total is known."""
        self._pages.append(dict(self.__dict__))
        self._startPage()

    def save(self) -> None:
        """Draw the furniture on every kept page, then write the document."""
        total = len(self._pages)
        for state in self._pages:
            self.__dict__.update(state)
            self._draw_furniture(total)
            super().showPage()
        super().save()

    def _draw_furniture(self, total: int) -> None:
        f = self.furniture
        top = PAGE_HEIGHT - MARGIN + 4 * mm
        self.saveState()
        self.setStrokeColor(ACCENT)
        self.setLineWidth(0.6)
        self.line(MARGIN, top - 2 * mm, PAGE_WIDTH - MARGIN, top - 2 * mm)
        self.setFont(FONT_BOLD, 8)
        self.setFillColor(ACCENT)
        self.drawString(MARGIN, top, f.get("title", ""))
        self.setFont(FONT, 8)
        self.setFillColor(colors.black)
        self.drawRightString(PAGE_WIDTH - MARGIN, top, f"Report {f.get('report_id', '')}   ·   Unit S/N {f.get('serial', '')}")
        bottom = MARGIN - 8 * mm
        self.setStrokeColor(RULE)
        self.line(MARGIN, bottom + 4 * mm, PAGE_WIDTH - MARGIN, bottom + 4 * mm)
        self.setFont(FONT, 7)
        self.setFillColor(RULE)
        self.drawString(MARGIN, bottom, f.get("footer", ""))
        self.setFillColor(colors.black)
        self.setFont(FONT_BOLD, 8)
        self.drawRightString(PAGE_WIDTH - MARGIN, bottom, f"page {self._pageNumber} of {total}")
        if f.get("banner"):  # simulated data: said on every page, between the header rule and the text
            self.setFillColor(VERDICT_COLOURS["fail"])
            self.setFont(FONT_BOLD, 7.5)
            self.drawCentredString(PAGE_WIDTH / 2, top - 5.5 * mm, f["banner"])
        if f.get("watermark"):
            self.setFillColor(colors.Color(0.75, 0.2, 0.2, alpha=0.16))
            self.translate(PAGE_WIDTH / 2, PAGE_HEIGHT / 2)
            self.rotate(55)
            self.drawPath(_outline(self, f["watermark"], 110), stroke=0, fill=1)
        self.restoreState()


@dataclass(frozen=True)
class PageMarks:
    """What a document says beyond its furniture.

    A watermark across every page, a banner under every header, and the document information's keywords (a
    certificate's manifest of inputs, :mod:`stableins.reporting.signing`).
    """

    watermark: str = ""
    banner: str = ""
    keywords: str = ""


def _outline(canvas: Any, text: str, size: float) -> Any:
    """Return ``text`` in bold as a filled outline centred on the origin.

    A watermark drawn as shapes, not as text, never mixes into the text layer a reader (or pdftotext) extracts.
    """
    from matplotlib.font_manager import FontProperties
    from matplotlib.path import Path as MplPath
    from matplotlib.textpath import TextPath

    glyphs = TextPath((0, 0), text, size=size, prop=FontProperties(family="DejaVu Sans", weight="bold"))
    box = glyphs.get_extents()
    dx, dy = -(box.x0 + box.x1) / 2, -(box.y0 + box.y1) / 2
    path = canvas.beginPath()
    vertices, codes = glyphs.vertices + (dx, dy), glyphs.codes
    i, start, here = 0, (0.0, 0.0), (0.0, 0.0)
    while i < len(codes):
        code = codes[i]
        if code == MplPath.MOVETO:
            start = here = (float(vertices[i][0]), float(vertices[i][1]))
            path.moveTo(*start)
            i += 1
        elif code == MplPath.LINETO:
            here = (float(vertices[i][0]), float(vertices[i][1]))
            path.lineTo(*here)
            i += 1
        elif code == MplPath.CURVE3:  # quadratic Bézier as the equivalent cubic
            (x0, y0), (cx, cy), (x1, y1) = here, vertices[i], vertices[i + 1]
            path.curveTo(x0 + 2 / 3 * (cx - x0), y0 + 2 / 3 * (cy - y0), x1 + 2 / 3 * (cx - x1), y1 + 2 / 3 * (cy - y1), x1, y1)
            here = (float(x1), float(y1))
            i += 2
        elif code == MplPath.CURVE4:
            path.curveTo(*vertices[i], *vertices[i + 1], *vertices[i + 2])
            here = (float(vertices[i + 2][0]), float(vertices[i + 2][1]))
            i += 3
        else:  # CLOSEPOLY, STOP
            path.close()
            here = start
            i += 1
    return path


class FloatingDocTemplate(BaseDocTemplate):
    """A document whose figures float.

    A :class:`Figure` that does not fit in what is left of the page lets the flowables after it that do fit go first
    (never past another figure or a heading that would start a new page), and is placed at the top of the next
    page — so a rigid figure never leaves half a page empty.
    """

    def handle_flowable(self, flowables: list[Flowable]) -> None:
        """Place the next flowable, letting flowables that fit go before a figure that does not."""
        first = flowables[0] if flowables else None
        if isinstance(first, Figure) and len(flowables) > 1:
            frame = self.frame
            width, room = frame._getAvailableWidth(), frame._y - frame._y1p
            _, needed = first.wrap(width, room)
            following = flowables[1]
            if needed > room and not isinstance(following, Figure) and self._fits(following, width, room):
                flowables[0], flowables[1] = following, first
        super().handle_flowable(flowables)

    @staticmethod
    def _fits(flowable: Flowable, width: float, room: float) -> bool:
        """Whether ``flowable`` fits whole in ``room`` (a conditional page break fits when it would not break)."""
        if isinstance(flowable, CondPageBreak):
            return room >= flowable.height
        if isinstance(flowable, Figure):
            return False
        _, height = flowable.wrap(width, room)
        return height + flowable.getSpaceBefore() + flowable.getSpaceAfter() <= room


def build(
    story: list[Flowable],
    out: Any,
    *,
    title: str,
    report_id: str,
    serial: str,
    footer: str,
    subject: str = "",
    marks: PageMarks | None = None,
) -> int:
    """Lay out ``story`` into ``out`` (a path or binary file object); returns the page count.

    ``marks``: a watermark across every page (a DRAFT) and a line under the header of every page (simulated data).
    """
    marks = marks or PageMarks()
    register_fonts()
    doc = FloatingDocTemplate(
        out,
        pagesize=A4,
        leftMargin=MARGIN,
        rightMargin=MARGIN,
        topMargin=MARGIN + HEADER * 0.4,
        bottomMargin=MARGIN + FOOTER * 0.2,
        title=f"{title} {report_id}",
        author="stableins",
        subject=subject,
        creator="stableins (reportlab)",
        keywords=marks.keywords,
    )
    frame = Frame(
        doc.leftMargin, doc.bottomMargin, doc.width, doc.height, id="body", leftPadding=0, rightPadding=0, topPadding=0, bottomPadding=0
    )
    doc.addPageTemplates([PageTemplate(id="page", frames=[frame])])
    furniture = {"title": title, "report_id": report_id, "serial": serial, "footer": footer}
    furniture |= {"watermark": marks.watermark, "banner": marks.banner}
    canvas_class = type("ReportCanvas", (NumberedCanvas,), {"furniture": furniture})
    doc.build(story, canvasmaker=canvas_class)
    return doc.page


def spacer(height_mm: float) -> Spacer:
    """Return vertical space of ``height_mm`` millimetres."""
    return Spacer(1, height_mm * mm)


def heading(text: str, level: str = "h1", room_mm: float = 30.0) -> list[Flowable]:
    """Return a heading that never ends a page: it moves to the next page unless ``room_mm`` of the frame remain below it."""
    return [CondPageBreak(room_mm * mm), Paragraph(text, styles()[level])]
