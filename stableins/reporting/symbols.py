r"""Typeset names and plain words for the certificate (reportlab markup and matplotlib mathtext).

A parameter is printed with the textbook symbol of its term (``beta_xy`` → β\ :sub:`xy`,
``theta20`` → θ\ :sub:`20`, ``K2_x`` → K\ :sub:`2,x`); the record id is printed once, in the
glossary, so that the certificate can be traced to the record.  Text taken from the record
(notes, determined combinations) is rewritten for people by :func:`prose`: every parameter id
becomes its symbol, ``*`` a product dot, ``-`` a true minus sign, command-line flags become
the words they stand for, and file names lose their folders.
"""

from __future__ import annotations

import re
from collections.abc import Iterable

MINUS = "\u2212"
GREEK = {"beta": "β", "theta": "θ", "phi": "φ", "delta": "δ", "omega": "ω", "zeta": "ζ"}
_MATHTEXT_GREEK = {"ε": r"\varepsilon", "β": r"\beta", "θ": r"\theta", "φ": r"\phi", "δ": r"\delta", "ω": r"\omega", "ζ": r"\zeta"}
#: Symbols of the heads of parameter ids: ``b`` and ``D`` are the system stage's bias (in units of g) and relative
#: scale-factor residuals.
_HEADS = {"sf": "SF", "bias": "δb", "b": "b", "D": "D", **GREEK, "lever": "l"}
#: Names whose generic form (head with subscripted tail) would read badly.
_SPECIAL = {
    "tilt_north": ("tilt", "N"),
    "tilt_east": ("tilt", "E"),
    "azimuth_error": ("δψ", "base"),
    "nonorth_12": ("δ", "⊥12"),
    "nonorth_23": ("δ", "⊥23"),
    "gyro_drift_x": ("ε", "x"),
    "gyro_drift_y": ("ε", "y"),
    "gyro_drift_z": ("ε", "z"),
}


def parts(parameter_id: str) -> tuple[str, str]:
    """Return ``(base, subscript)`` of a parameter's symbol; ``subscript`` may be empty.

    ``sf_x`` → (SF, x), ``bias_x`` → (δb, x), ``beta_xy`` → (β, xy), ``theta20`` → (θ, 20),
    ``K2_x`` → (K, 2,x), ``Kcc_xxy`` → (K, cc,xxy), ``Kt_bias_x`` → (K, t,b,x), ``lever_x_y`` → (l, x,y),
    ``ang1_inner_c`` → (a, 1,inner,c); other ids with an underscore: head and the rest as subscript.
    """
    if parameter_id in _SPECIAL:
        return _SPECIAL[parameter_id]
    match = re.fullmatch(r"theta(\d+)", parameter_id)
    if match:
        return "θ", match.group(1)
    head, _, tail = parameter_id.partition("_")
    tail = tail.replace("bias", "b").replace("_", ",")
    if head in _HEADS:
        return _HEADS[head], tail
    if head.startswith("ang") and head[3:].isdigit():
        return "a", f"{head[3:]},{tail}"
    if len(head) > 1 and head[0] in "KD" and head[1:].isalnum():
        return head[0], f"{head[1:]},{tail}" if tail else head[1:]
    return head, tail


def markup(parameter_id: str) -> str:
    """Return the symbol in reportlab's paragraph markup (``β<sub>xy</sub>``)."""
    base, sub = parts(parameter_id)
    return f"{base}<sub>{sub}</sub>" if sub else base


def mathtext(parameter_id: str) -> str:
    r"""Return the symbol in matplotlib mathtext (``$\beta_{xy}$``)."""
    base, sub = parts(parameter_id)
    special = {"δb": r"\delta b", "δψ": r"\delta\psi"}
    symbol = special.get(base) or _MATHTEXT_GREEK.get(base) or rf"\mathrm{{{base}}}"
    sub = sub.replace("⊥", r"\perp ")
    return f"${symbol}_{{{sub}}}$" if sub else f"${symbol}$"


def plain(parameter_id: str) -> str:
    """Return the symbol as plain text with the subscript run on (``βxy``, ``K2,x``): how a PDF's text layer reads it."""
    base, sub = parts(parameter_id)
    return base + sub


# ------------------------------------------------------------------ prose
#: Command-line syntax and stage parameters a record's notes may carry, and the words a certificate says instead (longest first).
_FLAGS = (
    (r"\(--gyro-drift X Y Z,? deg/h\)", "(in °/h, an input of the system stage)"),
    (r"--gyro-drift X Y Z", "the gyro drift in the platform frame"),
    (r"\(known_gyro_drift, rad/s\)", "(in °/h, an input of the system stage)"),
    (r"\(see diagnostics, --estimate-k2\)", "(the system stage's K₂ estimation)"),
    (r"\(see diagnostics, estimate_k2=True\)", "(the system stage's K₂ estimation)"),
    (r"\(estimate_k2=True\)", "(with the system stage's K₂ estimation)"),
    (r"\(--estimate-k2\)", "(with the system stage's K₂ estimation)"),
    (r"--estimate-k2", "the system stage's K₂ estimation"),
    (r"\(--bias-instability, --random-walk\)", "(the instrument's bias instability and random walk)"),
    (r"--bias-instability", "the bias instability"),
    (r"--random-walk", "the random walk"),
    (r"--no-loop-compensation", "no damping-loop compensation"),
    (r"--allow-missing", "missing positions allowed"),
    (r"\(given on the command line\)", "(given to the calibration)"),
    (r"given on the command line", "given to the calibration"),
    (r"\(docs/[\w./#-]+\)", ""),
)
_FLAG = re.compile(r"(?<![\w-])--[a-z][a-z0-9-]*")
_UNITS = (
    ("deg/h", "°/h"),
    ("m/s^2/sqrt(s)", "m/s²/√s"),
    ("m/s^2", "m/s²"),
    ("ug/g^2", "µg/g²"),
    ("ug/g^3", "µg/g³"),
    ("s^2/m", "s²/m"),
)
_WORD = re.compile(r"(?<![\w.])([A-Za-zα-ω][A-Za-z0-9]*(?:_[A-Za-z0-9]+)+|theta\d0)(?![A-Za-z0-9_])")
_SYSTEM_NAMES = {f"{h}_{a}" for h in ("b", "D") for a in "xyz"}
#: A path with at least one folder: ``/work/x/y.h5``, ``demo-output/system.h5``, ``C:\\x\\y.toml``.
_PATH = re.compile(r"(?<![\w/])(?:[A-Za-z]:\\|/|\.{1,2}/|[\w.-]+/)(?:[\w.+-]+[/\\])*([\w.+-]+\.[A-Za-z0-9]{1,5})\b")


def basename_paths(text: str) -> str:
    """Every file path in ``text`` replaced by its file name (no machine paths on a certificate)."""
    return _PATH.sub(lambda m: m.group(1), text)


def words_for_flags(text: str) -> str:
    """Command-line syntax replaced by the words it stands for (no ``--flag`` on a certificate)."""
    for pattern, words in _FLAGS:
        text = re.sub(pattern, words, text)
    return _FLAG.sub(lambda m: m.group(0)[2:].replace("-", " "), text)


def prose(text: str, ids: Iterable[str] = (), *, markup_symbols: bool = True) -> str:
    """Record text (notes, combinations) for people, as reportlab markup (escaped).

    Parameter ids (``ids`` and the standard ones) become symbols, ``a*b`` a product, `` - `` a minus
    sign, ``sinL`` ``sin L``, units their printed form, command-line flags words and paths file names.
    """
    from stableins.discovery.library import all_terms
    from stableins.reporting.document import escape

    known = set(all_terms()) | set(ids) | _SYSTEM_NAMES
    text = basename_paths(words_for_flags(str(text)))
    for ascii_unit, printed in _UNITS:
        text = text.replace(ascii_unit, printed)
    text = re.sub(r"(?<![A-Za-z])ug(?![A-Za-z])", "µg", text)
    text = re.sub(r"\b(sin|cos)(2?)L\b", lambda m: f"{m.group(1)}{'²' if m.group(2) else ''} L", text)
    text = re.sub(r"(?<=[\w)])\*(?=[\w(])", "·", text)
    text = re.sub(r"(?<=[\s(])-(?=[\s\w(])", MINUS, text)
    text = re.sub(r"[ \t]{2,}", " ", text).replace(" ,", ",").replace(" ;", ";").replace(" .", ".").replace("( ", "(")
    text = escape(text)
    if not markup_symbols:
        return text

    def symbol(match: re.Match[str]) -> str:
        word = match.group(1)
        if word in known:
            return markup(word)
        short = re.fullmatch(r"([A-Za-zα-ω])_([A-Za-z0-9]{1,3})", word)  # y_p, f_x, K_nl, ω_s
        return f"{short.group(1)}<sub>{short.group(2)}</sub>" if short else word

    return _WORD.sub(symbol, text)
