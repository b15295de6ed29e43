"""The one rule registry: every checker code and every rule id a reader raises.

Two tables, both defined exactly once, here:

* ``CODES`` — the stable diagnostic codes of ``fbaconf check`` (and of the harness's
  checks), each with a severity, the clause it enforces and a one-line description.
  Codes are stable: never renumbered or reused for another meaning — retire one instead.
* ``RULES`` — the short rule ids that typed input errors carry (``FbaconfInputError.rule``):
  the stage that raises it, a description, and for bitstream rules the checker code a
  stream that breaks it is reported under.

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

from dataclasses import dataclass

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


_rule(
    "animation-finite",
    "animation",
    "animation produced a non-finite vertex (frame …, vertex …); FAP values too large for the model?",
)
_rule(
    "arith-state",
    "bitstreams",
    "the arithmetic decoder reached an impossible state (interval or symbol search out of range): the bits are not an arithmetic-coded block",
    code=SYNTAX_ARITH_STATE,
)
_rule("baseline", "harness", "a baseline file cannot be read or is not a valid baseline")
_rule("bifs-command", "scenes", "command code …: only ReplaceScene (3) is supported")
_rule("bifs-config", "scenes", "BIFSConfig: isCommandStream = 0 (animation-mask streams are not supported)")
_rule("bifs-def-duplicate", "scenes", "a DEF name is defined twice")
_rule("bifs-def-name", "scenes", "bad or duplicate DEF name …")
_rule("bifs-depth", "scenes", "nodes nested deeper than …")
_rule("bifs-duplicate-field", "scenes", "a field is given twice in one node")
_rule("bifs-field-index", "scenes", "a field index (defID) beyond the node's field count")
_rule("bifs-field-type", "scenes", "field type … is not supported")
_rule("bifs-float", "scenes", "a float is NaN or infinite")
_rule("bifs-mf-count", "scenes", "an MF field's element count needs more bits than the stream has left")
_rule("bifs-mf-reserved", "scenes", "MF field reserved bit is 1 (predictive MF coding is not supported)")
_rule(
    "bifs-ndt",
    "scenes",
    "a … node cannot be coded inline where the node data type is … (DEF it where it belongs and USE it here)",
)
_rule("bifs-node-code", "scenes", "node code 0 in … (a node of a later BIFS version) is not supported")
_rule("bifs-node-id", "scenes", "too many DEF nodes")
_rule("bifs-node-type", "scenes", "expected a node, got …")
_rule("bifs-null", "scenes", "NULL is not allowed in an MFNode field")
_rule("bifs-padding", "scenes", "padding bits at the end of the access unit are not 0")
_rule("bifs-proto", "scenes", "a ReplaceScene with PROTOs (protoList = 1, D10): not supported")
_rule("bifs-routes", "scenes", "ROUTEs are not supported")
_rule("bifs-string", "scenes", "SFString is not UTF-8")
_rule("bifs-top", "scenes", "the top node is NULL or a USE")
_rule("bifs-trailing", "scenes", "bytes left after the access unit")
_rule("bifs-truncated", "scenes", "stream ends inside … (… bits needed, … left)")
_rule("bifs-unknown-field", "scenes", "a node has no field of that name")
_rule("bifs-unsupported-node", "scenes", "node … (code … in …) is outside the subset fbaconf reads")
_rule("bifs-use-undefined", "scenes", "USE …: no node was DEFined with this name before")
_rule("bifs-value", "scenes", "a float is not finite or outside the float32 range")
_rule("bt-bool", "scenes", "expected TRUE or FALSE, got …")
_rule("bt-def-duplicate", "scenes", "a DEF name is defined twice")
_rule("bt-def-name", "scenes", "a DEF name is not a valid identifier")
_rule("bt-depth", "scenes", "nodes nested deeper than …")
_rule("bt-duplicate-field", "scenes", "a field is given twice in one node")
_rule("bt-encoding", "scenes", "the scene file is not UTF-8 text")
_rule("bt-eof", "scenes", "unexpected end of file, expected …")
_rule("bt-node-type", "scenes", "a … node is not allowed here (allowed: …)")
_rule("bt-number", "scenes", "a number was expected")
_rule("bt-string", "scenes", "expected a quoted string, got …")
_rule("bt-syntax", "scenes", "a token other than the one the grammar expects here")
_rule("bt-token", "scenes", "a character that starts no BT token")
_rule("bt-token-size", "scenes", "a token longer than the BT reader's limit (1 MiB)")
_rule("bt-file", "scenes", "the scene file is not a regular file of at most 64 MiB (a FIFO, a device, too large)")
_rule("bt-unknown-field", "scenes", "a node has no field of that name")
_rule("bt-unknown-node", "scenes", "a node type outside the subset fbaconf reads")
_rule("bt-use-undefined", "scenes", "USE …: no node was DEFined with this name before")
_rule("calibration-empty", "animation", "calibration needs at least one feature point")
_rule(
    "calibration-degenerate",
    "animation",
    "the received feature points (or their texture projections) make a calibration system singular or ill-conditioned (condition number above 1e8)",
    code=SCENE_ILL_CONDITIONED,
)
_rule("calibration-transform", "animation", "calibration supports translation-only Transforms (… rotates or scales)")
_rule("coefficient-overflow", "bitstreams", "DC level … of FAP … exceeds …", code=SYNTAX_DCT)
_rule("dct-prediction", "bitstreams", "predicted segment of FAP … without an intra segment", code=SYNTAX_DCT)
_rule("empty", "bitstreams", "no frames to encode")
_rule(
    "expression-select-range",
    "bitstreams",
    "expression_select outside 0..6 (intra) or the predicted value leaves it (spec notes §2.2: 7 expressions)",
    code=SEM_EXPRESSION_SELECT,
)
_rule("facedef-borders-finite", "animation", "intervalBorders must be finite")
_rule(
    "facedef-borders-unsorted", "animation", "intervalBorders must be strictly increasing: border … (…) <= border … (…)"
)
_rule("facedef-borders-zero", "animation", "with more than one interval, one of the intervalBorders must be 0")
_rule("facedef-displacement-count", "animation", "displacements must be 3D vectors")
_rule("facedef-displacement-finite", "animation", "displacements must be finite")
_rule("facedef-fap-id", "animation", "fapID … out of range 1..68")
_rule("facedef-field-id", "animation", "fieldId … is not 1 (rotation), 2 (scale) or 3 (translation)")
_rule("facedef-interval-count", "animation", "intervalBorders needs at least 2 borders (1 interval), got …")
_rule("facedef-missing-node", "animation", "faceSceneGraphNode must name an IndexedFaceSet of the faceSceneGraph")
_rule("facedef-missing-vertex", "animation", "coordIndex[…] = … names a vertex the mesh does not have (it has …)")
_rule("facedef-transform-finite", "animation", "rotationDef/scaleDef/translationDef must be finite")
_rule("facedef-without-model", "animation", "faceDefTables need a downloaded model (faceSceneGraph) to animate")
_rule(
    "fap-text-write",
    "bitstreams",
    "the FAP data cannot be written as .fap text (frame rate not positive and finite, frame numbers)",
)
_rule("faps-missing", "bitstreams", "the FAP file does not exist")
_rule("faps-npz", "bitstreams", "the file is not a FapFrames .npz")
_rule("fapu-degenerate", "animation", "FAPU …0 = ….… - ….… = … must be positive on a neutral face")
_rule("fapu-missing-point", "animation", "FAPU … needs feature point …, which the model does not define")
_rule(
    "fdp-feature-point-count",
    "animation",
    "featurePointsCoord must list the 84 feature points in label order (unsent ones as …), got …",
)
_rule("fdp-texture-coord-count", "animation", "textureCoord must hold one (u, v) per feature point (84, label order)")
_rule("first-plane-intra", "bitstreams", "the first plane must be intra (D2)", code=SYNTAX_FIRST_PREDICTED)
_rule("fit-coef-finite", "animation", "coefficients must be finite")
_rule("fit-cycle", "animation", "the FAP interpolation graph has a cycle through nodes …")
_rule("fit-division-by-zero", "animation", "link (…, …): denominator is identically 0")
_rule("fit-duplicate-fap", "animation", "FIT node … lists a FAP twice")
_rule("fit-duplicate-link", "animation", "a FIT graph link appears twice")
_rule("fit-empty-node", "animation", "a FIT node lists no FAPs")
_rule("fit-exponent", "animation", "exponents must be >= 0")
_rule("fit-fap-range", "animation", "FAP number … out of range (-1 separator or 1..68)")
_rule("fit-field-count", "animation", "a FIT field has fewer entries than its layout needs (docs/animation.md)")
_rule("fit-graph-pairs", "animation", "Graph must hold (parent, child) pairs")
_rule(
    "fit-high-level-child", "animation", "node … is a child but holds FAP 1/2 (high-level FAPs cannot be interpolated)"
)
_rule("fit-impulse", "animation", "numeratorImpulse entries must be 0..…")
_rule("fit-missing-node", "animation", "link (…, …) names a node that does not exist (… nodes)")
_rule("frame-order", "bitstreams", "frame numbers must be >= 0")
_rule(
    "frame-rate",
    "bitstreams",
    "the frame rate to encode cannot be signalled (frame_rate 8 bits + seconds/16, optional 1000/1001)",
)
_rule("frame-rate-zero", "bitstreams", "the signalled frame rate is 0 (spec notes D6)", code=SEM_FRAME_RATE_ZERO)
_rule(
    "fuzz-setup",
    "fuzz",
    "a fuzz campaign cannot start: a target has no seed inputs, or the package to mutate cannot be made",
)
_rule("geometry-colors", "rendering", "vertex_colors must be finite float[…, 3], got shape …")
_rule("geometry-empty", "animation", "faceSceneGraph has no IndexedFaceSet")
_rule("geometry-finite", "animation", "Transform fields must be finite")
_rule("geometry-index", "animation", "coordIndex[…] = … names a point the Coordinate does not have (… points)")
_rule("geometry-material", "rendering", "specular (…) and shininess (…) must be finite and >= 0")
_rule("geometry-no-coord", "animation", "IndexedFaceSet without coord")
_rule("geometry-nonfinite", "rendering", "vertex position is not finite: …")
_rule("geometry-texcoords", "rendering", "part has a texture but no texcoords")
_rule("geometry-unsupported", "animation", "geometry … is not supported (IndexedFaceSet only)")
_rule(
    "high-level-range",
    "bitstreams",
    "a viseme/expression field to encode is outside its range (selects 0..14 / 0..6, blend/intensities 0..63)",
)
_rule("internal", "bitstreams", "internal decoder failure on malformed input: …: …")
_rule(
    "invalid-vlc",
    "bitstreams",
    "a DCT-mode variable-length code (Exp-Golomb or run/level Huffman) is invalid",
    code=SYNTAX_DCT,
)
_rule("io", "bitstreams", "a file cannot be read or written")
_rule(
    "pred-value-range",
    "bitstreams",
    "a predicted value outside the intra range (only under the other reading D4:value-range-enforced)",
)
_rule("reading", "bitstreams", "a reading of a provisional decision that bitstreams/data/readings.toml does not list")
_rule("manifest-claims", "harness", "a decoder manifest's claims are missing or not profile@level")
_rule("manifest-commands", "harness", "a decoder manifest's [commands] are missing or not argv lists")
_rule("manifest-env", "harness", "a decoder manifest's [env] is not a table of NAME = value")
_rule("manifest-faps-format", "harness", "a decoder manifest's faps_format is not fap or npz")
_rule(
    "manifest-inputs",
    "harness",
    "a decoder manifest's inputs are not a list of fba, fap, scene, bifs with a stream form",
)
_rule("manifest-key", "harness", "a decoder manifest misses a required key or has an unknown one")
_rule(
    "manifest-outputs",
    "harness",
    "a decoder manifest's outputs are not a list of faps, vertices, images its command names",
)
_rule("manifest-placeholder", "harness", "a decoder manifest's command uses an unknown placeholder")
_rule(
    "manifest-reject-codes",
    "harness",
    "a decoder manifest's reject_exit_codes are not exit codes 1..255 (other than 69, 126, 127)",
)
_rule(
    "manifest-sandbox",
    "harness",
    "a decoder manifest has a [sandbox] table: the lab, not the manifest, sets what a decoder sees (--sandbox-ro)",
)
_rule(
    "decoder-setup",
    "harness",
    "the decoder does not decode the claim's simplest valid stream, or every case ended the same way without a decoding: a set-up error (its stdout and stderr, the limits, the fix)",
)
_rule(
    "sandbox-view",
    "harness",
    "a folder the sandbox would show a decoder shows too much (/, a top-level folder, the fbaconf project, /proc…)",
)
_rule("certificate-json", "harness", "a certification package's JSON file is not JSON, or is nested too deeply")
_rule(
    "cluster",
    "harness",
    "--cluster is not local[:N] or tls://HOST:PORT, Dask is missing, the lab's TLS certificates are not given, or the scheduler cannot be reached",
)
_rule("certificate-key", "harness", "a signing key is missing, not PEM, or not Ed25519; or a key would be overwritten")
_rule("manifest-name", "harness", "a decoder manifest's name is not a plain name (it names the run folder)")
_rule(
    "output-unsafe",
    "harness",
    "a decoder's output is not a regular file (FIFO, device, symlink) or is larger than allowed",
)
_rule(
    "path-escape",
    "harness",
    "a path taken from data (case id, suite file, package entry, finding) would leave its folder",
)
_rule("manifest-tools", "harness", "a decoder manifest names an unknown tool")
_rule(
    "manifest-readings", "harness", "a decoder manifest declares a reading of a provisional decision that is not listed"
)
_rule("manifest-limits", "harness", "a decoder manifest's [limits] table is invalid")
_rule("manifest-missing", "harness", "no decoder manifest …: give a .toml path or one of the bundled adapters (…)")
_rule("manifest-options", "harness", "[options] mutant = …: unknown (known: …)")
_rule("manifest-python", "harness", "python = …: cannot import: …")
_rule("manifest-toml", "harness", "a decoder manifest is not valid TOML")
_rule("marker", "bitstreams", "a marker bit is 0 (spec notes §1.2)", code=SYNTAX_MARKER)
_rule(
    "object-mask", "bitstreams", "fba_object_mask …: only 01 (FAPs, no BAPs) is allowed (D1)", code=SYNTAX_OBJECT_MASK
)
_rule("option", "bitstreams", "fap_quant_per_frame must hold one value 0..31 per frame")
_rule("output-array-missing", "harness", "a decoder's .npz output lacks a required array")
_rule("output-dtype", "harness", "array '…' has dtype …, expected …")
_rule("output-fap-count", "harness", "a decoder's .fap output header declares another frame count than it holds")
_rule("output-fap-text", "harness", "unreadable FAP output: …… [rule …]")
_rule("output-format", "harness", "not an … .npz (no 'format' array)")
_rule("output-missing", "harness", "a decoder's output file is missing or not a regular file")
_rule("output-nonfinite", "harness", "a decoder's output holds NaN or infinite values")
_rule("output-npz", "harness", "not a readable .npz (zip) file: …")
_rule("output-range", "harness", "array '…' holds …, outside …..…")
_rule("output-shape", "harness", "array '…' has shape …, expected …")
_rule("output-too-large", "harness", "output is … bytes, more than the limit of …")
_rule("output-unreadable", "harness", "unreadable FAP output (…: …)")
_rule("output-unwritable", "rendering", "images cannot be written")
_rule("run-overflow", "bitstreams", "run of zeros goes past coefficient …", code=SYNTAX_DCT)
_rule("scenario-choice", "rendering", "a scenario key has a value outside its allowed choices")
_rule(
    "scenario-conflict",
    "rendering",
    "scenario keys that cannot be given together (e.g. camera.look_at with a direction)",
)
_rule("scenario-encoding", "rendering", "scenario is not UTF-8 (byte …)")
_rule("scenario-frame-range", "rendering", "frame … out of range: the sequence has … frames")
_rule("scenario-missing", "rendering", "a required scenario key is missing")
_rule("scenario-range", "rendering", "a scenario value is out of its range")
_rule("scenario-type", "rendering", "a scenario value has the wrong type")
_rule("scenario-unknown-key", "rendering", "a scenario key fbaconf does not know")
_rule("scenario-unreadable", "rendering", "a scenario file cannot be read")
_rule("scene-missing", "animation", "the scene file does not exist")
_rule("scene-no-face", "animation", "the scene has no Face node")
_rule("segment-length", "bitstreams", "segment length … exceeds …", code=SYNTAX_DCT)
_rule("speed-claim", "harness", "the claim given to the speed measurement is not a known profile@level")
_rule("speed-content", "harness", "generated stream lacks plane start codes / end code")
_rule(
    "start-code",
    "bitstreams",
    "stream must start with face_object_start_code 0x000001BA, found 0x…",
    code=SYNTAX_NOT_FACE,
)
_rule(
    "dct-stuffing",
    "bitstreams",
    "a DCT payload's stuffing bit after 22 consecutive zeros is not '1' (D9, the DCT mode's emulation prevention)",
    code=SYNTAX_DCT,
)
_rule(
    "start-code-emulation", "bitstreams", "the encoder cannot avoid a start-code emulation with plane start codes (D9)"
)
_rule(
    "stuffing",
    "bitstreams",
    "a 0 after 22 consecutive zeros in an arithmetic block (the stuffing bit must be 1; spec notes §3.3, D7)",
    code=SYNTAX_STUFFING,
)
_rule("suite-case", "conformance", "suite …: case …: kind … not one of …")
_rule("suite-manifest", "conformance", "a suite manifest (suite.json) is not a valid fbaconf suite manifest")
_rule("suite-missing", "conformance", "no suites at …: run `fbaconf suites build` first")
_rule("suite-spec", "conformance", "the suite specification (conformance/data/suites.toml) is invalid")
_rule(
    "suite-reference",
    "conformance",
    "a case's reference cannot be made: its scene does not compile or rests on an ill-conditioned system",
)
_rule("time-code", "bitstreams", "a time code field cannot be signalled (hours > 31)")
_rule("tolerance-key", "harness", "unknown … key(s) … (known: …)")
_rule("tolerance-order", "harness", "tolerances out of order (a warn limit above its fail limit)")
_rule("tolerance-type", "harness", "a tolerance is not a number")
_rule("tolerance-value", "harness", "a tolerance is negative")
_rule("toml-syntax", "rendering", "a TOML file is not valid TOML")
_rule("truncated", "bitstreams", "stream ends inside … (… bits needed, … left)", code=SYNTAX_TRUNCATED)
_rule("usage", "bitstreams", "--trace is for .bifs scenes")
_rule("value-overflow", "bitstreams", "FAP … value … overflows 32 bits", code=SEM_VALUE_OVERFLOW)
_rule("value-range", "bitstreams", "DC level … of FAP … in the segment at frame … is not codable (limit …)")
_rule(
    "viseme-select-range",
    "bitstreams",
    "viseme_select outside 0..14 (intra) or the predicted value leaves it (spec notes §2.2: 15 visemes)",
    code=SEM_VISEME_SELECT,
)
_rule(
    "fap-text-header",
    "fap-text",
    "header line missing or malformed: needs 'version name frame_rate count', frame_rate a positive finite number, count a non-negative integer",
    code=TEXT_HEADER,
    severity="error",
)
_rule("fap-text-version", "fap-text", "version is not 2.0, 2.1 or 2.2", code=TEXT_VERSION, severity="warning")
_rule(
    "fap-text-name",
    "fap-text",
    "name field contains whitespace (Greta) or is empty",
    code=TEXT_NAME,
    severity="warning",
)
_rule(
    "fap-text-mask-length",
    "fap-text",
    "mask line with 69 entries (Greta); the extra 69th entry is dropped",
    code=TEXT_MASK_LENGTH,
    severity="warning",
)
_rule("fap-text-mask-value", "fap-text", "mask entry other than 0 or 1", code=TEXT_MASK_VALUE, severity="error")
_rule(
    "fap-text-integer",
    "fap-text",
    "mask entry, frame number or value is not a decimal integer",
    code=TEXT_INTEGER,
    severity="error",
)
_rule(
    "fap-text-value-range",
    "fap-text",
    "frame number outside 0..2^31-1 or value outside the int32 range",
    code=TEXT_VALUE_RANGE,
    severity="error",
)
_rule(
    "fap-text-high-level-range",
    "fap-text",
    "viseme/expression field outside its defined range (selects 0..14 / 0..6, blend/intensities 0..63, def/init bits 0..1)",
    code=TEXT_HIGH_LEVEL_RANGE,
    severity="warning",
)
_rule(
    "fap-text-truncated",
    "fap-text",
    "the file ends inside a frame (values missing at end of file)",
    code=TEXT_TRUNCATED,
    severity="error",
)
_rule(
    "fap-text-frame-order",
    "fap-text",
    "frame number smaller than the previous frame's",
    code=TEXT_FRAME_ORDER,
    severity="warning",
)
_rule(
    "fap-text-frame-duplicate",
    "fap-text",
    "frame number already used by an earlier frame",
    code=TEXT_FRAME_DUPLICATE,
    severity="warning",
)
_rule(
    "fap-text-frame-beyond",
    "fap-text",
    "frame number greater than the header's declared frame count",
    code=TEXT_FRAME_BEYOND,
    severity="warning",
)
_rule(
    "fap-text-frame-count",
    "fap-text",
    "number of frames in the file differs from the header's count",
    code=TEXT_FRAME_COUNT,
    severity="warning",
)
_rule(
    "dct-unsupported",
    "bitstreams",
    "coding_type 1 (DCT segment mode) is not supported by this decoder build "
    "(the checker reports the unchecked rest; raised by decoders built without the DCT mode)",
    code=CHECK_DCT,
)


def code_for_rule(rule: str, default: str) -> str:
    """The checker code a stream breaking decoder rule ``rule`` is reported under."""
    info = RULES.get(rule)
    return info.code if info is not None and info.code is not None else default
