"""Checker diagnostics: the registry of stable codes, the Diagnostic record, folding.

Every code is defined exactly once, below, with its severity, the clause it enforces and a
one-line description; ``docs/ISSUES.md`` is generated from this registry
(``python -m fbaconf.profiles.catalogue``). Codes are stable: a code is never renumbered or
reused for another meaning — retire it instead.

Code families:
  FAP-INPUT-*     the input could not be read at all
  FAP-SYNTAX-*    face object syntax (start codes, markers, reserved values, stuffing, truncation)
  FAP-SEM-*       semantics of well-formed fields (frame rate, time codes, high-level ranges)
  FAP-DECISION-*  the stream depends on an fbaconf decision (D1-D8 of the spec notes) where a
                  plausible other reading exists: warnings, never errors
  FAP-PROFILE-*   a tool outside the claimed profile
  FAP-LEVEL-*     a limit of the claimed level exceeded
  FAP-CLAIM-*     claim-level results (--smallest-claim)
  FAP-SCENE-*     the optional scene file
  FAP-CHECK-*     limits of the checker itself (a part it could not check, an internal failure)
"""
from __future__ import annotations

from dataclasses import dataclass, field

SEVERITIES = ("error", "warning", "info")
SEVERITY_RANK = {s: i for i, s in enumerate(SEVERITIES)}

NOTES = "14496-2 face_object syntax as read in the spec notes"


@dataclass(frozen=True)
class CodeInfo:
    code: str
    severity: str
    clause: str
    description: str


REGISTRY: dict[str, CodeInfo] = {}


def _define(code: str, severity: str, clause: str, description: str) -> str:
    if code in REGISTRY:
        raise RuntimeError(f"diagnostic code {code} defined twice")
    if severity not in SEVERITIES:
        raise RuntimeError(f"{code}: bad severity {severity}")
    REGISTRY[code] = CodeInfo(code, severity, clause, description)
    return code


# ---------------------------------------------------------------------------- input
INPUT_UNREADABLE = _define(
    "FAP-INPUT-001", "error", "fbaconf check (command line)",
    "The input file cannot be read (missing, a directory, permission denied).")

# ---------------------------------------------------------------------------- syntax
SYNTAX_TOO_SHORT = _define(
    "FAP-SYNTAX-001", "error", f"{NOTES} §1.1 (face_object_start_code)",
    "The input is empty or shorter than a 32-bit start code: not a face object stream.")
SYNTAX_NOT_FACE = _define(
    "FAP-SYNTAX-002", "error", f"{NOTES} §1.1 (face_object_start_code 0x000001BA)",
    "The input does not start with face_object_start_code 0x000001BA: not a face object stream.")
SYNTAX_TRUNCATED = _define(
    "FAP-SYNTAX-003", "error", f"{NOTES} §1.2 (face_object_plane syntax)",
    "The stream ends inside a field or an arithmetic-coded block (truncated).")
SYNTAX_MARKER = _define(
    "FAP-SYNTAX-004", "error", f"{NOTES} §1.2/§1.4 (marker_bit)",
    "A marker_bit (before a group mask, in a new min/max list, in a time code) is 0.")
SYNTAX_OBJECT_MASK = _define(
    "FAP-SYNTAX-005", "error", f"{NOTES} §1.2 (fba_object_mask); decision D1",
    "fba_object_mask is not 01: BAPs (or no parameters) are not a face stream's reserved value.")
SYNTAX_FIRST_PREDICTED = _define(
    "FAP-SYNTAX-006", "error", "decision D2 (the first plane is intra)",
    "The first face_object_plane is predicted (is_intra = 0).")
SYNTAX_STUFFING = _define(
    "FAP-SYNTAX-007", "error", f"{NOTES} §3.3 (start-code emulation prevention); decision D7",
    "Inside an arithmetic block, the bit after 22 consecutive zeros is not the stuffing '1'.")
SYNTAX_ARITH_STATE = _define(
    "FAP-SYNTAX-008", "error", f"{NOTES} §3.3 (arithmetic decoding)",
    "Corrupt arithmetic-coded block: the decoder state leaves the coding interval.")
SYNTAX_NO_END_CODE = _define(
    "FAP-SYNTAX-009", "warning", f"{NOTES} §1.1 (visual_object_sequence_end_code 0x000001B1)",
    "The stream ends without next_start_code() stuffing and the end code 0x000001B1.")
SYNTAX_TRAILING = _define(
    "FAP-SYNTAX-010", "warning", f"{NOTES} §1.1 (visual_object_sequence_end_code)",
    "Data follows the end code; a decoder ignores it.")
SYNTAX_UNEXPECTED_START_CODE = _define(
    "FAP-SYNTAX-011", "error", f"{NOTES} §1.1/§1.2 (start codes)",
    "A start code other than face_object_plane_start_code or the end code ends the face object.")
SYNTAX_OTHER = _define(
    "FAP-SYNTAX-012", "error", f"{NOTES} §1.2 (face_object_plane syntax)",
    "The stream cannot be parsed further for another reason (the message names the rule broken).")
SYNTAX_DCT = _define(
    "FAP-SYNTAX-013", "error", "decision D8 (DCT segment mode, provisional tables; spec notes §4)",
    "Invalid DCT plane-group data: bad VLC codeword, run past the segment, segment too long, coefficient too large.")

# ---------------------------------------------------------------------------- semantics
SEM_FRAME_RATE_ZERO = _define(
    "FAP-SEM-001", "error", f"{NOTES} §1.2 (frame_rate, seconds); decision D6",
    "A signalled frame rate is 0 (frame_rate = 0 and seconds = 0).")
SEM_TIME_CODE_RANGE = _define(
    "FAP-SEM-002", "error", f"{NOTES} §1.2 (time_code hours/minutes/seconds)",
    "A time code field is out of range: hours > 23, minutes > 59 or seconds > 59.")
SEM_TIME_BACKWARDS = _define(
    "FAP-SEM-003", "warning", f"{NOTES} §1.2 (time code); decision D6 (plane times)",
    "A time code is earlier than the whole second in which the previous plane lies (time goes backwards).")
SEM_VISEME_SELECT = _define(
    "FAP-SEM-004", "error", "decision D5 (viseme_select 0..14)",
    "A decoded viseme_select1/2 is outside 0..14.")
SEM_EXPRESSION_SELECT = _define(
    "FAP-SEM-005", "error", "decision D5 (expression_select 0..6)",
    "A decoded expression_select1/2 is outside 0..6.")
SEM_INTENSITY = _define(
    "FAP-SEM-006", "error", "decision D5; spec notes §2.2 (blend/intensity 0..63)",
    "A decoded viseme_blend or expression_intensity1/2 is outside 0..63 (or above the top of its D5 intra alphabet when that exceeds 63).")
SEM_VALUE_OVERFLOW = _define(
    "FAP-SEM-007", "error", f"{NOTES} §3.4 (reconstruction)",
    "A reconstructed FAP value overflows 32 bits.")
SEM_SINGLE_SYMBOL = _define(
    "FAP-SEM-008", "info", "decision D4 (alphabets from the signalled ranges)",
    "A coded FAP's intra or predicted alphabet has a single symbol (e.g. a list value 0): it carries no information.")

# ---------------------------------------------------------------------------- decisions
DECISION_QUANT_NO_LISTS = _define(
    "FAP-DECISION-001", "warning", "decision D4 (alphabets recomputed at each intra plane)",
    "fap_quant changes at an intra plane that does not send all four new min/max lists; S1 would keep the old scaling.")
DECISION_UNIDIRECTIONAL_NEGATIVE = _define(
    "FAP-DECISION-002", "warning", "decision D4 (symmetric ranges also for unidirectional FAPs)",
    "A unidirectional FAP (3, 14, 41, 42, 47) decodes to a negative value.")
DECISION_DEFAULT_ROUNDING = _define(
    "FAP-DECISION-003", "warning", "decision D4 (default ranges rounded to multiples of 60)",
    "A coded FAP relies on a default range whose rounding to a multiple of 60 changes its alphabet.")
DECISION_NO_FRAME_RATE = _define(
    "FAP-DECISION-004", "warning", "decision D6 (25 Hz when no frame rate is signalled)",
    "The stream never signals a frame rate; it is timed at 25 Hz (S1's decoder would use 30 Hz).")
DECISION_LOOKAHEAD_STUFFING = _define(
    "FAP-DECISION-005", "warning", "decision D7 (end of an arithmetic block, the look-ahead)",
    "A stuffing position falls inside an arithmetic block's 14-bit look-ahead: D7 and a plain 14-bit rewind disagree.")
DECISION_MASK_INTERPOLATE = _define(
    "FAP-DECISION-006", "warning", "decision D3 (mask types 01 keep / 10 may interpolate)",
    "Mask type 10 leaves a previously set FAP uncoded: D3 frees it, S1 keeps its value.")
DECISION_HIGH_LEVEL_QUANT = _define(
    "FAP-DECISION-007", "warning", "decision D5 (blend/intensity alphabets divided by fap_quant)",
    "Visemes or expressions are coded with fap_quant > 1: their alphabet depends on D5.")

# ---------------------------------------------------------------------------- profile / level / claim
PROFILE_TOOL = _define(
    "FAP-PROFILE-001", "error", "profiles-and-levels.md: Profiles (allowed tools)",
    "The stream or scene uses a tool outside the claimed profile.")
LEVEL_BITRATE = _define(
    "FAP-LEVEL-001", "error", "profiles-and-levels.md: Levels (max FAP stream bitrate per face)",
    "The bitrate over a sliding one-second window exceeds the claimed level's limit.")
LEVEL_FRAME_RATE = _define(
    "FAP-LEVEL-002", "error", "profiles-and-levels.md: Levels (max coded frame rate)",
    "The number of coded frames in a sliding one-second window exceeds the claimed level's coded frame rate.")
LEVEL_FACES = _define(
    "FAP-LEVEL-003", "error", "profiles-and-levels.md: Levels (face objects decoded at once)",
    "More face objects than the claimed level allows.")
LEVEL_FDP_POINTS = _define(
    "FAP-LEVEL-004", "error", "profiles-and-levels.md: Levels (max feature points in FDP)",
    "The FDP sends more feature points than the claimed level allows.")
LEVEL_FIT_NODES = _define(
    "FAP-LEVEL-005", "error", "profiles-and-levels.md: Levels (max FIT graph nodes)",
    "The FIT graph has more nodes than the claimed level allows.")
LEVEL_FIT_LINKS = _define(
    "FAP-LEVEL-006", "error", "profiles-and-levels.md: Levels (max FIT graph links)",
    "The FIT graph has more links than the claimed level allows.")
LEVEL_FIT_TERMS = _define(
    "FAP-LEVEL-007", "error", "profiles-and-levels.md: Levels (max FIT polynomial terms per function)",
    "A FIT rational function has more terms than the claimed level allows.")
LEVEL_TEXTURE = _define(
    "FAP-LEVEL-008", "error", "profiles-and-levels.md: Levels (max texture size)",
    "The FDP texture is larger than the claimed level allows.")
LEVEL_MESH_VERTICES = _define(
    "FAP-LEVEL-009", "error", "profiles-and-levels.md: Levels (max downloaded mesh vertices)",
    "The downloaded face model has more vertices than the claimed level allows.")
LEVEL_FDT_ENTRIES = _define(
    "FAP-LEVEL-010", "error", "profiles-and-levels.md: Levels (max FaceDefTables entries)",
    "The FaceDefTables have more entries (fapID x mesh/transform) than the claimed level allows.")
LEVEL_INTERVALS = _define(
    "FAP-LEVEL-011", "error", "profiles-and-levels.md: Levels (max intervals per FaceDefMesh)",
    "A FaceDefMesh has more intervals than the claimed level allows.")
CLAIM_NONE = _define(
    "FAP-CLAIM-001", "error", "profiles-and-levels.md: Conformance claim",
    "No profile@level defined by the suite admits the stream (--smallest-claim).")

# ---------------------------------------------------------------------------- scene / checker
SCENE_UNAVAILABLE = _define(
    "FAP-SCENE-001", "warning", "fbaconf check --scene (scene reader fbaconf.scenes.bt)",
    "A scene file was given but this build has no scene reader: the scene was not checked.")
SCENE_INVALID = _define(
    "FAP-SCENE-002", "error", "14496-1 BIFS Face node family as read in the spec notes §6 (BT text)",
    "The scene file cannot be read or parsed.")
CHECK_DCT = _define(
    "FAP-CHECK-001", "warning", f"{NOTES} §4 / decision D8 (DCT segment mode)",
    "A plane uses DCT segment coding and the decoder in this build cannot parse it: checking stops there.")
CHECK_INTERNAL = _define(
    "FAP-CHECK-002", "error", "fbaconf check (internal)",
    "The checker failed internally (a bug in fbaconf): the stream was not fully checked.")


# ---------------------------------------------------------------------------- records
@dataclass(frozen=True)
class Location:
    bit_offset: int | None = None
    plane: int | None = None
    frame: int | None = None
    fap: int | None = None
    node_path: str | None = None
    time_ms: float | None = None

    @property
    def byte_offset(self) -> int | None:
        return None if self.bit_offset is None else self.bit_offset // 8

    def to_dict(self) -> dict:
        d: dict = {}
        if self.bit_offset is not None:
            d["byte_offset"] = self.bit_offset // 8
            d["bit"] = self.bit_offset % 8
            d["bit_offset"] = self.bit_offset
        for k in ("plane", "frame", "fap", "node_path"):
            v = getattr(self, k)
            if v is not None:
                d[k] = v
        if self.time_ms is not None:
            d["time_ms"] = round(float(self.time_ms), 3)
        return d

    def __str__(self) -> str:
        parts = []
        if self.bit_offset is not None:
            parts.append(f"byte {self.bit_offset // 8} bit {self.bit_offset % 8}")
        if self.plane is not None:
            parts.append(f"plane {self.plane}")
        if self.frame is not None:
            parts.append(f"frame {self.frame}")
        if self.fap is not None:
            parts.append(f"FAP {self.fap}")
        if self.node_path:
            parts.append(self.node_path)
        return ", ".join(parts) or "stream"

    def sort_key(self) -> tuple:
        return (self.bit_offset if self.bit_offset is not None else 1 << 62, self.node_path or "")


@dataclass(frozen=True)
class Diagnostic:
    code: str
    severity: str
    message: str
    clause: str
    location: Location = field(default_factory=Location)

    def to_dict(self) -> dict:
        return {"code": self.code, "severity": self.severity, "message": self.message, "clause": self.clause,
                "location": self.location.to_dict()}

    def __str__(self) -> str:
        return f"{self.severity}: {self.code} at {self.location}: {self.message} [{self.clause}]"


def diag(code: str, message: str, *, bit_offset: int | None = None, plane: int | None = None,
         frame: int | None = None, fap: int | None = None, node_path: str | None = None,
         time_ms: float | None = None) -> Diagnostic:
    """A diagnostic for a registered code (severity and clause come from the registry)."""
    info = REGISTRY[code]
    return Diagnostic(code, info.severity, message, info.clause,
                      Location(None if bit_offset is None else int(bit_offset), plane, frame, fap, node_path,
                               time_ms))


@dataclass
class Issue:
    """Repeated diagnostics of one code folded: the first message, a count and the first locations."""
    code: str
    severity: str
    clause: str
    message: str
    count: int
    locations: list[Location]

    def to_dict(self) -> dict:
        return {"code": self.code, "severity": self.severity, "clause": self.clause, "message": self.message,
                "count": self.count, "locations": [loc.to_dict() for loc in self.locations],
                "omitted_locations": self.count - len(self.locations)}


def fold(diags: list[Diagnostic], first: int = 5) -> list[Issue]:
    """Fold diagnostics by code, in order of first occurrence: count + the first ``first`` locations."""
    out: dict[str, Issue] = {}
    for d in diags:
        it = out.get(d.code)
        if it is None:
            out[d.code] = Issue(d.code, d.severity, d.clause, d.message, 1, [d.location])
        else:
            it.count += 1
            if len(it.locations) < first:
                it.locations.append(d.location)
    return list(out.values())


def select(diags: list[Diagnostic], only: list[str] | None = None, ignore: list[str] | None = None) -> list[Diagnostic]:
    """Keep the codes in ``only`` (all when empty) and drop those in ``ignore``. A pattern ending
    in '*' matches a prefix (``FAP-DECISION-*``)."""
    def match(code: str, pats) -> bool:
        return any(code == p or (p.endswith("*") and code.startswith(p[:-1])) for p in pats)
    out = diags
    if only:
        out = [d for d in out if match(d.code, only)]
    if ignore:
        out = [d for d in out if not match(d.code, ignore)]
    return out


def counts(diags) -> dict[str, int]:
    c = {s: 0 for s in SEVERITIES}
    for d in diags:
        c[d.severity] += getattr(d, "count", 1)
    return c


__all__ = ["REGISTRY", "SEVERITIES", "CodeInfo", "Diagnostic", "Issue", "Location", "counts", "diag", "fold",
           "select"]
