"""The one rule registry: every checker code and every rule id a reader raises.

Two tables, both defined exactly once, here:

* ``CODES`` — the stable diagnostic codes of ``fbaconf check`` (and of the harness's
  checks), each with a severity, the clause it enforces and a one-line description.
  Codes are stable: never renumbered or reused for another meaning — retire one instead.
* ``RULES`` — the short rule ids that typed input errors carry (``FbaconfInputError.rule``):
  the stage that raises it, a description, and for bitstream rules the checker code a
  stream that breaks it is reported under (a table: ``data/rules.toml``).

``docs/ISSUES.md`` is generated from both (``python -m fbaconf.profiles.catalogue``), and a
test asserts that every rule id raised anywhere in the source is registered here.

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
  FAP-TEXT-*      an ASCII .fap file (``fbaconf check F.fap``: the text rules of its reader)
  FAP-CHECK-*     limits of the checker itself (a part it could not check, an internal failure)
"""

from __future__ import annotations

import tomllib
from dataclasses import dataclass
from importlib import resources

SEVERITIES = ("error", "warning", "info")
SEVERITY_RANK = {s: i for i, s in enumerate(SEVERITIES)}

NOTES = "14496-2 face_object syntax as read in the spec notes"


@dataclass(frozen=True)
class CodeInfo:
    code: str
    severity: str
    clause: str
    description: str


CODES: dict[str, CodeInfo] = {}


def _define(code: str, severity: str, clause: str, description: str) -> str:
    if code in CODES:
        raise RuntimeError(f"diagnostic code {code} defined twice")
    if severity not in SEVERITIES:
        raise RuntimeError(f"{code}: bad severity {severity}")
    CODES[code] = CodeInfo(code, severity, clause, description)
    return code


# ---------------------------------------------------------------------------- input
INPUT_UNREADABLE = _define(
    "FAP-INPUT-001",
    "error",
    "fbaconf check (command line)",
    "The input file cannot be read (missing, a directory, permission denied).",
)

# ---------------------------------------------------------------------------- syntax
SYNTAX_TOO_SHORT = _define(
    "FAP-SYNTAX-001",
    "error",
    f"{NOTES} §1.1 (face_object_start_code)",
    "The input is empty or shorter than a 32-bit start code: not a face object stream.",
)
SYNTAX_NOT_FACE = _define(
    "FAP-SYNTAX-002",
    "error",
    f"{NOTES} §1.1 (face_object_start_code 0x000001BA)",
    "The input does not start with face_object_start_code 0x000001BA: not a face object stream.",
)
SYNTAX_TRUNCATED = _define(
    "FAP-SYNTAX-003",
    "error",
    f"{NOTES} §1.2 (face_object_plane syntax)",
    "The stream ends inside a field or an arithmetic-coded block (truncated).",
)
SYNTAX_MARKER = _define(
    "FAP-SYNTAX-004",
    "error",
    f"{NOTES} §1.2/§1.4 (marker_bit)",
    "A marker_bit (before a group mask, in a new min/max list, in a time code) is 0.",
)
SYNTAX_OBJECT_MASK = _define(
    "FAP-SYNTAX-005",
    "error",
    f"{NOTES} §1.2 (fba_object_mask); decision D1",
    "fba_object_mask is not 01: BAPs (or no parameters) are not a face stream's reserved value.",
)
SYNTAX_FIRST_PREDICTED = _define(
    "FAP-SYNTAX-006",
    "error",
    "decision D2 (the first plane is intra)",
    "The first face_object_plane is predicted (is_intra = 0).",
)
SYNTAX_STUFFING = _define(
    "FAP-SYNTAX-007",
    "error",
    f"{NOTES} §3.3 (start-code emulation prevention); decision D7",
    "Inside an arithmetic block, the bit after 22 consecutive zeros is not the stuffing '1'.",
)
SYNTAX_ARITH_STATE = _define(
    "FAP-SYNTAX-008",
    "error",
    f"{NOTES} §3.3 (arithmetic decoding)",
    "Corrupt arithmetic-coded block: the decoder state leaves the coding interval.",
)
SYNTAX_NO_END_CODE = _define(
    "FAP-SYNTAX-009",
    "warning",
    f"{NOTES} §1.1 (visual_object_sequence_end_code 0x000001B1)",
    "The stream ends without next_start_code() stuffing and the end code 0x000001B1.",
)
SYNTAX_TRAILING = _define(
    "FAP-SYNTAX-010",
    "warning",
    f"{NOTES} §1.1 (visual_object_sequence_end_code)",
    "Data follows the end code; a decoder ignores it.",
)
SYNTAX_UNEXPECTED_START_CODE = _define(
    "FAP-SYNTAX-011",
    "error",
    f"{NOTES} §1.1/§1.2 (start codes)",
    "A start code other than face_object_plane_start_code or the end code ends the face object.",
)
SYNTAX_OTHER = _define(
    "FAP-SYNTAX-012",
    "error",
    f"{NOTES} §1.2 (face_object_plane syntax)",
    "The stream cannot be parsed further for another reason (the message names the rule broken).",
)
SYNTAX_DCT = _define(
    "FAP-SYNTAX-013",
    "error",
    "decision D8 (DCT segment mode, provisional tables; spec notes §4)",
    "Invalid DCT plane-group data: bad VLC codeword, run past the segment, segment too long, coefficient too large.",
)
SYNTAX_EMULATION = _define(
    "FAP-SYNTAX-014",
    "error",
    "decision D9 (no start-code emulation)",
    "A byte-aligned 0x000001 that is not a start code the syntax consumed: a decoder or demultiplexer that "
    "scans for start codes cuts the stream there.",
)

# ---------------------------------------------------------------------------- semantics
SEM_FRAME_RATE_ZERO = _define(
    "FAP-SEM-001",
    "error",
    f"{NOTES} §1.2 (frame_rate, seconds); decision D6",
    "A signalled frame rate is 0 (frame_rate = 0 and seconds = 0).",
)
SEM_TIME_CODE_RANGE = _define(
    "FAP-SEM-002",
    "error",
    f"{NOTES} §1.2 (time_code hours/minutes/seconds)",
    "A time code field is out of range: hours > 23, minutes > 59 or seconds > 59.",
)
SEM_TIME_BACKWARDS = _define(
    "FAP-SEM-003",
    "warning",
    f"{NOTES} §1.2 (time code); decision D6 (plane times)",
    "A time code is earlier than the whole second in which the previous plane lies (time goes backwards).",
)
SEM_VISEME_SELECT = _define(
    "FAP-SEM-004",
    "error",
    "spec notes §2.2 (the 15 visemes: viseme_select 0..14)",
    "A decoded viseme_select1/2 is outside 0..14 (the viseme table's size: an error whatever the D5 reading).",
)
SEM_EXPRESSION_SELECT = _define(
    "FAP-SEM-005",
    "error",
    "spec notes §2.2 (the 7 expressions: expression_select 0..6)",
    "A decoded expression_select1/2 is outside 0..6 (the expression table's size: an error whatever the D5 reading).",
)
SEM_INTENSITY = _define(
    "FAP-SEM-006",
    "error",
    "spec notes §2.2 (blend/intensity 0..63), §2.3 (intra alphabet x fap_quant)",
    "A decoded viseme_blend or expression_intensity1/2 is outside 0..63 (or above the top of its intra alphabet when "
    "that exceeds 63) under both readings of the blend/intensity alphabet.",
)
SEM_VALUE_OVERFLOW = _define(
    "FAP-SEM-007", "error", f"{NOTES} §3.4 (reconstruction)", "A reconstructed FAP value overflows 32 bits."
)
SEM_INTENSITY_D5 = _define(
    "FAP-SEM-009",
    "error",
    "decision D5 (blend/intensity alphabet 0..floor((63 + floor(q/2))/q), not 0..ceil(63/q))",
    "A decoded viseme_blend or expression_intensity1/2 is above 63 and above the top of D5's intra alphabet, but within "
    "the top of the other reading's (0..ceil(63/q), x q): out of range only under D5.",
)
SEM_SINGLE_SYMBOL = _define(
    "FAP-SEM-008",
    "info",
    "decision D4 (alphabets from the signalled ranges)",
    "A coded FAP's intra or predicted alphabet has a single symbol (e.g. a list value 0): it carries no information.",
)

# ---------------------------------------------------------------------------- decisions
DECISION_QUANT_NO_LISTS = _define(
    "FAP-DECISION-001",
    "warning",
    "decision D4 (alphabets recomputed at each intra plane)",
    "A coded FAP's bound was last scaled at another fap_quant (a list, or the defaults at the first intra plane) "
    "and no new list replaced it: D4 recomputes its alphabet, S1 keeps the old one.",
)
DECISION_UNIDIRECTIONAL_NEGATIVE = _define(
    "FAP-DECISION-002",
    "warning",
    "decision D4 (symmetric ranges also for unidirectional FAPs)",
    "A unidirectional FAP (3, 14, 41, 42, 47) decodes to a negative value.",
)
DECISION_DEFAULT_ROUNDING = _define(
    "FAP-DECISION-003",
    "warning",
    "decision D4 (default ranges rounded to multiples of 60)",
    "A coded FAP relies on a default range whose rounding to a multiple of 60 changes its alphabet.",
)
DECISION_NO_FRAME_RATE = _define(
    "FAP-DECISION-004",
    "warning",
    "decision D6 (25 Hz when no frame rate is signalled)",
    "The stream never signals a frame rate; it is timed at 25 Hz (S1's decoder would use 30 Hz).",
)
DECISION_LOOKAHEAD_STUFFING = _define(
    "FAP-DECISION-005",
    "warning",
    "decision D7 (end of an arithmetic block, the look-ahead)",
    "A stuffing position falls inside an arithmetic block's 14-bit look-ahead: D7 and a plain 14-bit rewind disagree.",
)
DECISION_MASK_INTERPOLATE = _define(
    "FAP-DECISION-006",
    "warning",
    "decision D3 (mask types 01 keep / 10 may interpolate)",
    "Mask type 10 leaves a previously set FAP uncoded: D3 frees it, S1 keeps its value.",
)
DECISION_HIGH_LEVEL_QUANT = _define(
    "FAP-DECISION-007",
    "warning",
    "decision D5 (blend/intensity alphabet 0..floor((63 + floor(q/2))/q); 0..ceil(63/q) is the other reading)",
    "Visemes or expressions are coded where the blend/intensity alphabet depends on D5: at a fap_quant where "
    "floor((63 + floor(q/2))/q) and ceil(63/q) differ (10, 12, 15, 19, 20, 26-31), or at fap_quant 0 after an intra "
    "plane with fap_quant >= 2 (S1 recomputes the alphabet only for fap_quant > 0 and keeps that plane's).",
)
DECISION_PRED_OUTSIDE_INTRA = _define(
    "FAP-DECISION-008",
    "warning",
    "decision D4 (a predicted value may leave the range the intra alphabet codes)",
    "A predicted plane decodes a FAP (previous value + difference, notes §3.4) to a value outside the range its intra "
    "alphabet can code: valid under D4, as S1's encoder writes it and S1's decoder adds without a check; a decoder "
    "that takes the intra range as the value range rejects the stream.",
)

# ---------------------------------------------------------------------------- profile / level / claim
PROFILE_TOOL = _define(
    "FAP-PROFILE-001",
    "error",
    "profiles-and-levels.md: Profiles (allowed tools)",
    "The stream or scene uses a tool outside the claimed profile.",
)
LEVEL_BITRATE = _define(
    "FAP-LEVEL-001",
    "error",
    "profiles-and-levels.md: Levels (max FAP stream bitrate per face)",
    "The bitrate over a sliding one-second window exceeds the claimed level's limit.",
)
LEVEL_FRAME_RATE = _define(
    "FAP-LEVEL-002",
    "error",
    "profiles-and-levels.md: Levels (max coded frame rate)",
    "The number of coded frames in a sliding one-second window exceeds the claimed level's coded frame rate.",
)
LEVEL_FACES = _define(
    "FAP-LEVEL-003",
    "error",
    "profiles-and-levels.md: Levels (face objects decoded at once)",
    "More face objects than the claimed level allows.",
)
LEVEL_FDP_POINTS = _define(
    "FAP-LEVEL-004",
    "error",
    "profiles-and-levels.md: Levels (max feature points in FDP)",
    "The FDP sends more feature points than the claimed level allows.",
)
LEVEL_FIT_NODES = _define(
    "FAP-LEVEL-005",
    "error",
    "profiles-and-levels.md: Levels (max FIT graph nodes)",
    "The FIT graph has more nodes than the claimed level allows.",
)
LEVEL_FIT_LINKS = _define(
    "FAP-LEVEL-006",
    "error",
    "profiles-and-levels.md: Levels (max FIT graph links)",
    "The FIT graph has more links than the claimed level allows.",
)
LEVEL_FIT_TERMS = _define(
    "FAP-LEVEL-007",
    "error",
    "profiles-and-levels.md: Levels (max FIT polynomial terms per function)",
    "A FIT rational function has more terms than the claimed level allows.",
)
LEVEL_TEXTURE = _define(
    "FAP-LEVEL-008",
    "error",
    "profiles-and-levels.md: Levels (max texture size)",
    "The FDP texture is larger than the claimed level allows.",
)
LEVEL_MESH_VERTICES = _define(
    "FAP-LEVEL-009",
    "error",
    "profiles-and-levels.md: Levels (max downloaded mesh vertices)",
    "The downloaded face model has more vertices than the claimed level allows.",
)
LEVEL_FDT_ENTRIES = _define(
    "FAP-LEVEL-010",
    "error",
    "profiles-and-levels.md: Levels (max FaceDefTables entries)",
    "The FaceDefTables have more entries (fapID x mesh/transform) than the claimed level allows.",
)
LEVEL_INTERVALS = _define(
    "FAP-LEVEL-011",
    "error",
    "profiles-and-levels.md: Levels (max intervals per FaceDefMesh)",
    "A FaceDefMesh has more intervals than the claimed level allows.",
)
CLAIM_NONE = _define(
    "FAP-CLAIM-001",
    "error",
    "profiles-and-levels.md: Conformance claim",
    "No profile@level defined by the suite admits the stream (--smallest-claim).",
)

# ---------------------------------------------------------------------------- .fap text
TEXT_CLAUSE = "spec notes §7 (ASCII .fap files); readings: docs/fap-text.md"
TEXT_HEADER = _define(
    "FAP-TEXT-001",
    "error",
    TEXT_CLAUSE,
    "The header line is missing or malformed: it needs 'version name frame_rate count', frame_rate a positive finite number, count a non-negative integer.",
)
TEXT_VERSION = _define(
    "FAP-TEXT-002", "warning", TEXT_CLAUSE, "The version is not 2.0, 2.1 or 2.2; the file is read with the 2.x layout."
)
TEXT_NAME = _define(
    "FAP-TEXT-003",
    "warning",
    TEXT_CLAUSE,
    "The header's name field contains whitespace (as Greta writes it) or is empty.",
)
TEXT_MASK_LENGTH = _define(
    "FAP-TEXT-004",
    "warning",
    TEXT_CLAUSE,
    "A mask line has 69 entries (Greta's form); the extra 69th entry is dropped.",
)
TEXT_MASK_VALUE = _define("FAP-TEXT-005", "error", TEXT_CLAUSE, "A mask entry is not 0 or 1.")
TEXT_INTEGER = _define(
    "FAP-TEXT-006",
    "error",
    TEXT_CLAUSE,
    "A mask entry, frame number or value is not a decimal integer (FAP values are integers).",
)
TEXT_VALUE_RANGE = _define(
    "FAP-TEXT-007", "error", TEXT_CLAUSE, "A frame number is outside 0..2^31-1 or a value outside the int32 range."
)
TEXT_HIGH_LEVEL_RANGE = _define(
    "FAP-TEXT-008",
    "warning",
    TEXT_CLAUSE,
    "A viseme/expression field is outside its defined range (selects 0..14 / 0..6, blend/intensities 0..63, def/init bits 0..1).",
)
TEXT_TRUNCATED = _define(
    "FAP-TEXT-009", "error", TEXT_CLAUSE, "The file ends inside a frame: values are missing at the end of the file."
)
TEXT_FRAME_ORDER = _define(
    "FAP-TEXT-010", "warning", TEXT_CLAUSE, "A frame number is smaller than the previous frame's."
)
TEXT_FRAME_DUPLICATE = _define(
    "FAP-TEXT-011", "warning", TEXT_CLAUSE, "A frame number was already used by an earlier frame."
)
TEXT_FRAME_BEYOND = _define(
    "FAP-TEXT-012", "warning", TEXT_CLAUSE, "A frame number is greater than the header's declared frame count."
)
TEXT_FRAME_COUNT = _define(
    "FAP-TEXT-013",
    "warning",
    TEXT_CLAUSE,
    "The number of frames in the file differs from the header's frame count (reported at the count).",
)
TEXT_MASK_SHORT = _define(
    "FAP-TEXT-014",
    "error",
    TEXT_CLAUSE,
    "A mask line has fewer than 68 entries (reported at its end); the checker reads on as if the missing "
    "entries were 0, so what follows is not reported as a cascade of shifted values.",
)

# ---------------------------------------------------------------------------- scene / checker
SCENE_UNAVAILABLE = _define(
    "FAP-SCENE-001",
    "warning",
    "fbaconf check --scene (scene reader fbaconf.scenes.bt)",
    "A scene file was given but this build has no scene reader: the scene was not checked.",
)
SCENE_INVALID = _define(
    "FAP-SCENE-002",
    "error",
    "14496-1 BIFS Face node family as read in the spec notes §6 (BT text)",
    "The scene file cannot be read or parsed.",
)
SCENE_INTEROP_FDM = _define(
    "FAP-SCENE-003",
    "warning",
    "decision D10 (BIFS as GPAC codes it); Ostermann 1998 §2.3.2 (FaceDefMesh)",
    "FaceDefMesh.faceSceneGraphNode references an IndexedFaceSet, as the seed defines it; GPAC's MP4Box types "
    "the field SF3DNode and refuses such a USE when decoding (the bits are the same): an interop hazard.",
)
SCENE_ILL_CONDITIONED = _define(
    "FAP-SCENE-004",
    "error",
    "fbaconf decision: calibration by RBF interpolation (docs/animation.md, animation/rbf.py)",
    "The scene's FDP calibration would rest on an ill-conditioned interpolation system (condition number above "
    "the documented bound 1e8): feature points, or their texture-space projections, too close to each other "
    "without coinciding, or nearly coplanar. The reference refuses it (rule calibration-degenerate) instead of "
    "letting the result depend on the platform's LAPACK.",
)
CHECK_DCT = _define(
    "FAP-CHECK-001",
    "warning",
    f"{NOTES} §4 / decision D8 (DCT segment mode)",
    "A plane uses DCT segment coding and the decoder in this build cannot parse it: checking stops there.",
)
CHECK_INTERNAL = _define(
    "FAP-CHECK-002",
    "error",
    "fbaconf check (internal)",
    "The checker failed internally (a bug in fbaconf): the stream was not fully checked.",
)


# ---------------------------------------------------------------------------- rule ids
@dataclass(frozen=True)
class RuleInfo:
    rule: str
    stage: str
    description: str
    code: str | None = None
    severity: str = "error"


RULES: dict[str, RuleInfo] = {}


def _rule(rule: str, stage: str, description: str, *, code: str | None = None, severity: str = "error") -> None:
    if rule in RULES:
        raise RuntimeError(f"rule {rule} defined twice")
    if code is not None and code not in CODES:
        raise RuntimeError(f"rule {rule}: unknown code {code}")
    if severity not in SEVERITIES:
        raise RuntimeError(f"rule {rule}: bad severity {severity}")
    RULES[rule] = RuleInfo(rule, stage, description, code, severity)


for _r in tomllib.loads(resources.files("fbaconf").joinpath("data/rules.toml").read_text("utf-8"))["rule"]:
    _rule(_r["id"], _r["stage"], _r["description"], code=_r.get("code"), severity=_r.get("severity", "error"))


def code_for_rule(rule: str, default: str) -> str:
    """The checker code a stream breaking decoder rule ``rule`` is reported under."""
    info = RULES.get(rule)
    return info.code if info is not None and info.code is not None else default
