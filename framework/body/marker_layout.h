// Marker layouts: which labelled markers sit on which body vertices.
//
// The file format is MoSh++'s layout JSON (REFERENCE.md 7.1):
//   {"surface_model_type": "smplx",
//    "markersets": [{"type": "body", "distance_from_skin": 0.0095,
//                    "indices": {"C7": 3832, "LFHD": [12, 40], ...}}]}
// A superset may list several vertex ids per label. Markers are ordered by
// type, then by label (byte order, like Python's sorted()); REFERENCE.md 3.1:
// this order defines the label ids 0..L-1 of the labeller's output columns.
//
// Built-in layouts with real label names are defined anatomically (a rule
// per label: a point on the bone axis between two core joints plus a
// direction in the rest frame) and resolved on any body with the 24 core
// joints by casting a ray from the bone axis to the skin; see
// MakeBuiltinLayout().
#pragma once

#include "framework/body/body_model.h"
#include "framework/io/marker_labels.h"

#include <Eigen/Core>

#include <filesystem>
#include <string>
#include <string_view>
#include <vector>

namespace soma {

/// MoSh++'s default marker-centre-to-skin distance for body markers, metres.
inline constexpr double kDefaultDistanceFromSkin = 0.0095;

/// Marker type of the wrist-bar markers (LWRA, LWRB, RWRA, RWRB) in the
/// built-in layouts; every other built-in label has type "body".
inline constexpr std::string_view kWristMarkerType = "wrist";

/// distance_from_skin of the wrist-bar markers in the built-in layouts,
/// metres. CMU/HDM05 and Plug-in Gait wrist markers sit on the two ends of a
/// wrist bar that holds them off the skin over the radial and ulnar styloids
/// (CMU marker guide: "LWRA/LWRB: left wrist bar thumb side / pinkie side").
/// SOMA's `wrist_markers_on_stick` and MoSh++'s "wrist" marker type use
/// 0.039 m (REFERENCE.md 3.3, 7.1); we keep that value, untuned. Effect on
/// `soma realism` (HDM05 + CMU medians: LWRA-LWRB 0.1425 m, RWRA-RWRB
/// 0.1405 m), body distance 0.0095 m -> 0.039 m:
///   procedural: wrist pair 0.086 -> 0.1425 m, forearm segment -9.6% -> +2.0%;
///   MakeHuman:  wrist pair 0.068 -> 0.126 m, forearm segment -15.7% -> -4.9%.
/// The pair grows by ~2 mm per mm of distance (the two normals are nearly
/// opposite); the remaining MakeHuman gap is its thinner wrist, not the bar.
inline constexpr double kWristBarDistanceFromSkin = 0.039;

/// A marker layout (or a superset of several).
struct MarkerLayout {
  struct Marker {
    std::string label;  // canonical or vendor label, e.g. "LFHD"
    std::string type =
        "body";  // MoSh marker type: body, face, finger_left, ...
    std::vector<int> vertex_ids;  // >= 1 ids; several in a superset
    double distance_from_skin = kDefaultDistanceFromSkin;  // metres
    bool operator==(const Marker& other) const = default;
  };

  std::string surface_model_type =
      "smplx";                  // body model the vertex ids refer to
  std::vector<Marker> markers;  // sorted by (type, label) after Sort()

  /// Orders markers by (type, label), the label-id order of REFERENCE.md 3.1.
  void Sort();
  int num_markers() const { return static_cast<int>(markers.size()); }
  /// Labels in marker order.
  std::vector<std::string> Labels() const;
  /// Index of `label` in `markers`, or -1.
  int FindLabel(std::string_view label) const;

  bool operator==(const MarkerLayout& other) const = default;
};

/// Parses a layout from JSON text. Errors (malformed JSON with line:col,
/// missing or unknown keys, wrong types, negative or non-integer vertex ids,
/// duplicate types or labels) are IoError naming `source_name` and the key
/// path, e.g. "layout.json: markersets[0].indices.LFHD: ...".
MarkerLayout ParseMarkerLayout(std::string_view json_text,
                               std::string_view source_name);

/// ReadFile + ParseMarkerLayout.
MarkerLayout ReadMarkerLayout(const std::filesystem::path& path);

/// The layout as MoSh++ writes it: keys sorted, indent 2; a label with one
/// vertex id is written as an integer, with several as a list.
std::string MarkerLayoutToJson(const MarkerLayout& layout);

/// Atomic write of MarkerLayoutToJson (temp file + rename).
void WriteMarkerLayout(const MarkerLayout& layout,
                       const std::filesystem::path& path);

// ---- Labels.

// StripSubjectPrefix ("meinard:LFHD" -> "LFHD") is in io/marker_labels.h.

/// One vendor-name -> canonical-name entry.
struct MarkerLabelAlias {
  std::string alias;
  std::string canonical;
};

/// The alias table, sorted by alias. Canonical names are the CMU/HDM05
/// labels where those exist (our real evaluation data use them: RBAC, LWRA,
/// LWRB, LFWT, LBWT, ...) and MoSh++ names otherwise. It maps
///  - Vicon Plug-in Gait names: LASI->LFWT, RASI->RFWT, LPSI->LBWT,
///    RPSI->RBWT, RBAK->RBAC (and LBAK->LBAC);
///  - MoSh++ wrist names: LIWR->LWRA, LOWR->LWRB, RIWR->RWRA, ROWR->RWRB
///    (MoSh++ maps the other way; we keep the CMU names canonical);
///  - long-form names from MoSh++'s general_labels_map (L_KNEE->LKNE,
///    HEAD_TOP->ARIEL, STERNUM->STRN, L_INKNEE->LKNI, ...).
/// "RBAC-1" (a near-empty duplicate trajectory in CMU files) is deliberately
/// not mapped, so it cannot collide with RBAC.
const std::vector<MarkerLabelAlias>& MarkerLabelAliases();

/// Strips the subject prefix and blanks, upper-cases, then maps an alias to
/// its canonical name ("meinard:lasi" -> "LFWT"). Unknown names pass through
/// (upper-cased).
std::string CanonicalMarkerLabel(std::string_view label);

/// Every label name this module knows: the canonical labels with anatomical
/// rules, the vendor names of the built-in layouts and all aliases (sorted).
const std::vector<std::string>& KnownMarkerLabels();
bool IsKnownMarkerLabel(std::string_view label);

/// Maps every label through CanonicalMarkerLabel; labels that become equal
/// are merged (their distinct vertex ids concatenated, first-seen order).
/// Throws ConfigError if merged labels have different types.
MarkerLayout CanonicalizeLayout(const MarkerLayout& layout);

struct MergeLayoutsOptions {
  bool canonicalize_labels =
      true;  // apply CanonicalMarkerLabel first (as SOMA does)
};

/// The superset (REFERENCE.md 3.1, merge_marker_layouts): union of labels,
/// each with the list of distinct vertex ids it has across the layouts.
/// Throws ConfigError if the layouts refer to different surface models, a
/// label has different types, or one type has different distance_from_skin.
MarkerLayout MergeLayouts(const std::vector<MarkerLayout>& layouts,
                          const MergeLayoutsOptions& options = {});

// ---- Name maps (`task.name_map`): a user's marker names onto ours.

/// A name map file: one YAML mapping `their_name: our_name`, e.g.
///   LeftKnee: LKNE
///   Hips_L: LFWT
/// Keys are compared to capture labels without the subject prefix and
/// case-insensitively (like CanonicalMarkerLabel, but without aliases); the
/// map is applied before the alias table.
struct MarkerNameMap {
  std::string source;  // the file, for messages
  /// (their name as written, our name as written), file order.
  std::vector<std::pair<std::string, std::string>> entries;

  bool empty() const { return entries.empty(); }
  /// Our name for a capture label `label` (subject prefix ignored), or
  /// `label` unchanged when the map does not name it.
  std::string Apply(std::string_view label) const;
  std::vector<std::string> Apply(const std::vector<std::string>& labels) const;
};

/// Parses a name map. IoError "<source>: <key>: ..." (one line) for
/// malformed YAML, a top level that is not a mapping, a value that is not a
/// string (number, bool, null, list, mapping), an empty name, and two keys
/// that are the same label (case and subject prefix ignored).
MarkerNameMap ParseMarkerNameMap(std::string_view yaml_text,
                                 std::string_view source);

/// ReadFile + ParseMarkerNameMap (IoError naming the file if unreadable).
MarkerNameMap ReadMarkerNameMap(const std::filesystem::path& path);

/// Checks a name map against the labels it maps onto (a layout's or a
/// labeller's, compared through CanonicalMarkerLabel): IoError naming the
/// file and key for a target that is not one of `labels` (listing them), or
/// for two keys mapped onto the same label. `what` names the labels in the
/// message, e.g. "the layout" or "the labeller".
void CheckMarkerNameMap(const MarkerNameMap& map,
                        const std::vector<std::string>& labels,
                        std::string_view what);

// ---- Validation against a body.

struct LayoutCheckOptions {
  bool allow_unknown_labels =
      false;  // accept labels not in KnownMarkerLabels()
  bool require_surface_model_match = true;  // surface_model_type == body.name
};

/// Throws IoError naming `source` and the offending label for a vertex id
/// outside [0, V), an empty id list, a negative or non-finite distance, and
/// (unless allowed) an unknown label or a surface-model mismatch.
void ValidateLayoutForBody(const MarkerLayout& layout,
                           const BodyModel& body,
                           std::string_view source,
                           const LayoutCheckOptions& options = {});

/// ReadMarkerLayout + ValidateLayoutForBody (source = the path).
MarkerLayout LoadMarkerLayoutForBody(const std::filesystem::path& path,
                                     const BodyModel& body,
                                     const LayoutCheckOptions& options = {});

// ---- Built-in layouts.

/// "cmu41", "pig39", "soma53", "superset89".
const std::vector<std::string>& BuiltinLayoutNames();

/// The labels of a built-in layout in label-id order, i.e. the order of
/// MakeBuiltinLayout(body, name).Labels(): sorted by (marker type, label)
/// (BuiltinMarkerType), so the wrist-bar labels come last ("body" < "wrist").
/// Throws ConfigError listing the names for an unknown name.
///  - cmu41: the CMU / HDM05 41-marker set (the paper's HDM05 validation
///    layout), CMU names (RBAC, LWRA/LWRB, LFWT/LBWT, LSHN, LMT5).
///  - pig39: Vicon Plug-in Gait full body, Vicon names (RBAK, LASI, LPSI,
///    LTIB).
///  - soma53: cmu41 + 12 common MoSh++ markers that disambiguate limb
///    rotation and the head (ARIEL, LELBIN, RELBIN, LKNI, RKNI, LMT1, RMT1,
///    LBSH, RBSH, LFSH, RFSH, SACR). Our choice, documented here: the paper
///    lists a 53-marker dataset (KIT, Table 3) without its labels.
///  - superset89: the canonical union of the above (55 labels) plus 34 more
///    MoSh++ labels spread over the body (LBCEP, LFRMIN, LTHMB, LFTHI, LBTHI,
///    LTHILO, LCLF, LTIBIN, LCHST, LBLLY, LNECK, LSCAP, LFOOT, LBUM and
///    their right partners; LBAC, T8, CHIN, MFWT, BHEAD, FHEAD).
const std::vector<std::string>& BuiltinLayoutLabels(std::string_view name);

/// The canonical labels that have an anatomical placement rule (89), sorted
/// by label.
const std::vector<std::string>& AnatomicalMarkerLabels();

/// The marker type a built-in layout gives `label` (looked up through
/// CanonicalMarkerLabel, so LIWR/LOWR/RIWR/ROWR count as wrist labels):
/// kWristMarkerType for LWRA, LWRB, RWRA, RWRB, "body" otherwise.
std::string BuiltinMarkerType(std::string_view label);

/// distance_from_skin of a built-in marker type: kWristBarDistanceFromSkin
/// for kWristMarkerType, kDefaultDistanceFromSkin otherwise.
double BuiltinDistanceFromSkin(std::string_view type);

/// Resolves a built-in layout on `body` (mean shape): every label is placed
/// by its anatomical rule (aliases resolve through their canonical rule) on
/// the nearest vertex of the skin point where a ray from the bone axis (head
/// markers: from the head centre measured on the skin) leaves the body
/// (SkinVertexAlongRay).
/// surface_model_type = body.name; each marker has type
/// BuiltinMarkerType(label) and distance BuiltinDistanceFromSkin(type)
/// (body 0.0095 m, wrist bar kWristBarDistanceFromSkin), so built-in layouts
/// merge (MergeLayouts) without distance conflicts.
MarkerLayout MakeBuiltinLayout(const BodyModel& body, std::string_view name);

/// Removes markers from a layout (`layout.exclude`, e.g. a subset layout for
/// SOMA's Table 4). Names are compared through CanonicalMarkerLabel, so
/// RBAK excludes RBAC. Returns the positions in `labels` that are kept, in
/// order. Throws ConfigError naming `key` for a name that matches no label,
/// or if nothing would be left.
std::vector<int> KeptLabelPositions(const std::vector<std::string>& labels,
                                    const std::vector<std::string>& exclude,
                                    std::string_view key);

/// `layout` without the markers `exclude` names (KeptLabelPositions).
MarkerLayout ExcludeMarkers(const MarkerLayout& layout,
                            const std::vector<std::string>& exclude,
                            std::string_view key);

/// The skin vertex where the ray origin + t * dir (t > 0) leaves the mesh:
/// the nearest hit on an exit face (outward normal along `dir`), so inner
/// surfaces facing the origin (mouth or eye cavities, double layers) are
/// passed through; the nearest hit of any face if no exit face is hit. Of
/// the hit triangle, the vertex nearest the hit point; -1 if the ray misses.
/// Faces are counter-clockwise seen from outside (BodyModel convention).
int SkinVertexAlongRay(const Eigen::Vector3d& origin,
                       const Eigen::Vector3d& dir,
                       const Eigen::Matrix3Xd& vertices,
                       const Eigen::Matrix3Xi& faces);

/// Marker positions (3 x L, markers order) for posed `vertices` and their
/// `normals`: v[vid] + n[vid] * distance_from_skin, using each label's first
/// vertex id.
Eigen::Matrix3Xd MarkerPositions(const MarkerLayout& layout,
                                 const Eigen::Matrix3Xd& vertices,
                                 const Eigen::Matrix3Xd& normals);

}  // namespace soma
