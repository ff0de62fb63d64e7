#include "framework/body/makehuman_body.h"

#include "framework/core/error.h"
#include "framework/core/file.h"
#include "framework/core/json.h"
#include "framework/io/npz.h"

#include <Eigen/Cholesky>
#include <Eigen/SparseCore>
#include <fmt/format.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdlib>
#include <map>
#include <memory>
#include <numeric>
#include <string_view>
#include <utility>
#include <vector>

namespace soma {
namespace {

using SparseRowMatrix = Eigen::SparseMatrix<double, Eigen::RowMajor>;

constexpr const char* kObjFile = "3dobjs/base.obj";
constexpr const char* kGroupsFile = "mesh_metadata/basemesh_vertex_groups.json";
constexpr const char* kRigFile = "rigs/standard/rig.cmu_mb.json";
constexpr const char* kWeightsFile = "rigs/standard/weights.cmu_mb.json";
constexpr const char* kTargetsDir = "targets/macrodetails";
constexpr const char* kTPoseFile = "poses/cmu_mb_fk/t-pose.json";
constexpr const char* kBodyGroup = "body";

/// Stature component: relative scale per unit beta.
constexpr double kStatureScalePerBeta = 0.04;
/// Regressor fit: minimum and maximum number of support vertices, and the
/// ridge on the (row-normalised) constraint Gram matrix.
constexpr int kMinSupport = 200;
constexpr int kMaxSupport = 400;
constexpr double kRegressorRidge = 1e-10;
/// Skinning weights of a left (right) joint on vertices with x below
/// -margin (above +margin) are asset noise and removed (metres).
constexpr double kMidlineMargin = 0.01;
/// Regressor weights below this magnitude are dropped.
constexpr double kRegressorDropTolerance = 1e-10;

// ---------------------------------------------------------------------------
// Frame: MakeHuman (Y up, facing +Z, decimetres) -> ours (Z up, facing -Y,
// metres).

Eigen::Vector3d ToOurs(double x, double y, double z, double scale) {
  return scale * Eigen::Vector3d(x, -z, y);
}

std::filesystem::path RequireFile(const std::filesystem::path& dir,
                                  const char* relative) {
  std::filesystem::path path = dir / relative;
  if (!std::filesystem::is_regular_file(path)) {
    throw IoError(
        fmt::format("MakeHuman body: missing file '{}'", path.string()));
  }
  return path;
}

// Rethrows JSON access errors (which do not know the file) with the file.
template <typename F>
auto WithFile(const std::filesystem::path& path, F&& f) -> decltype(f()) {
  try {
    return f();
  } catch (const IoError& e) {
    const std::string message = e.what();
    if (message.rfind(path.string(), 0) == 0) throw;
    throw IoError(fmt::format("{}: {}", path.string(), message));
  }
}

const Json& Member(const Json& object,
                   std::string_view key,
                   std::string_view where) {
  const Json* value = JsonFind(object, key);
  if (value == nullptr)
    throw IoError(fmt::format("{}: missing '{}'", where, key));
  return *value;
}

// ---------------------------------------------------------------------------
// OBJ.

struct ObjMesh {
  Eigen::Matrix3Xd vertices;                 // all vertices, ours (metres)
  std::vector<std::vector<int>> body_faces;  // polygons of the body group
};

std::vector<std::string_view> SplitWhitespace(std::string_view line) {
  std::vector<std::string_view> tokens;
  size_t i = 0;
  while (i < line.size()) {
    while (i < line.size() &&
           (line[i] == ' ' || line[i] == '\t' || line[i] == '\r'))
      ++i;
    const size_t start = i;
    while (i < line.size() && line[i] != ' ' && line[i] != '\t' &&
           line[i] != '\r')
      ++i;
    if (i > start) tokens.push_back(line.substr(start, i - start));
  }
  return tokens;
}

double ParseDouble(std::string_view token, const std::string& where) {
  const std::string text(token);
  char* end = nullptr;
  const double value = std::strtod(text.c_str(), &end);
  if (end != text.c_str() + text.size() || !std::isfinite(value)) {
    throw IoError(fmt::format("{}: bad number '{}'", where, text));
  }
  return value;
}

long ParseInteger(std::string_view token, const std::string& where) {
  const std::string text(token);
  char* end = nullptr;
  const long value = std::strtol(text.c_str(), &end, 10);
  if (text.empty() || end != text.c_str() + text.size()) {
    throw IoError(fmt::format("{}: bad integer '{}'", where, text));
  }
  return value;
}

ObjMesh ReadObj(const std::filesystem::path& path, double scale) {
  const std::string text = ReadFile(path);
  ObjMesh mesh;
  std::vector<Eigen::Vector3d> vertices;
  std::string group;
  int line_number = 0;
  size_t pos = 0;
  while (pos < text.size()) {
    size_t end = text.find('\n', pos);
    if (end == std::string::npos) end = text.size();
    const std::string_view line(text.data() + pos, end - pos);
    pos = end + 1;
    ++line_number;
    if (line.empty() || line[0] == '#') continue;
    const std::vector<std::string_view> tokens = SplitWhitespace(line);
    if (tokens.empty()) continue;
    const std::string where = fmt::format("{}:{}", path.string(), line_number);
    if (tokens[0] == "v") {
      if (tokens.size() < 4)
        throw IoError(fmt::format("{}: vertex needs 3 coordinates", where));
      vertices.push_back(ToOurs(ParseDouble(tokens[1], where),
                                ParseDouble(tokens[2], where),
                                ParseDouble(tokens[3], where),
                                scale));
    } else if (tokens[0] == "g") {
      group = tokens.size() > 1 ? std::string(tokens[1]) : std::string();
    } else if (tokens[0] == "f" && group == kBodyGroup) {
      if (tokens.size() < 4)
        throw IoError(fmt::format("{}: face needs 3 or more vertices", where));
      std::vector<int> face;
      for (size_t k = 1; k < tokens.size(); ++k) {
        const std::string_view index_text =
            tokens[k].substr(0, tokens[k].find('/'));
        long index = ParseInteger(index_text, where);
        if (index < 0)
          index += static_cast<long>(vertices.size()) + 1;  // relative index
        if (index < 1 || index > static_cast<long>(vertices.size())) {
          throw IoError(fmt::format("{}: face vertex {} outside 1..{}",
                                    where,
                                    index,
                                    vertices.size()));
        }
        face.push_back(static_cast<int>(index - 1));
      }
      mesh.body_faces.push_back(std::move(face));
    }
  }
  if (vertices.empty() || mesh.body_faces.empty()) {
    throw IoError(fmt::format("{}: no vertices or no faces in group '{}'",
                              path.string(),
                              kBodyGroup));
  }
  mesh.vertices.resize(3, static_cast<Eigen::Index>(vertices.size()));
  for (size_t i = 0; i < vertices.size(); ++i)
    mesh.vertices.col(i) = vertices[i];
  return mesh;
}

// ---------------------------------------------------------------------------
// Vertex groups: name -> vertex indices (inclusive ranges in the JSON).

std::map<std::string, std::vector<int>> ReadVertexGroups(
    const std::filesystem::path& path, int num_vertices) {
  return WithFile(path, [&] {
    const Json root = ReadJsonFile(path);
    std::map<std::string, std::vector<int>> groups;
    for (const auto& [name, ranges] : JsonObject(root)) {
      std::vector<int>& indices = groups[name];
      for (const Json& range : JsonArray(ranges)) {
        const Json::array_t& pair = JsonArray(range);
        if (pair.size() != 2) {
          throw IoError(fmt::format(
              "group '{}': ranges must be [first, last] pairs", name));
        }
        const int64_t first = JsonInt(pair[0]);
        const int64_t last = JsonInt(pair[1]);
        if (first < 0 || last < first || last >= num_vertices) {
          throw IoError(fmt::format(
              "group '{}': range [{}, {}] outside the {} mesh vertices",
              name,
              first,
              last,
              num_vertices));
        }
        for (int64_t i = first; i <= last; ++i)
          indices.push_back(static_cast<int>(i));
      }
    }
    return groups;
  });
}

// ---------------------------------------------------------------------------
// Macro targets.

struct Target {
  std::vector<int> indices;
  std::vector<Eigen::Vector3d> offsets;  // ours (metres)
};

class TargetCache {
 public:
  TargetCache(std::filesystem::path dir, int num_vertices, double scale)
      : dir_(std::move(dir)), num_vertices_(num_vertices), scale_(scale) {}

  const Target& Get(const std::string& name) {
    auto it = cache_.find(name);
    if (it != cache_.end()) return it->second;
    const std::filesystem::path path = dir_ / (name + ".target.gz");
    if (!std::filesystem::is_regular_file(path)) {
      throw IoError(fmt::format("MakeHuman body: missing target file '{}'",
                                path.string()));
    }
    const std::string text = ReadGzipFile(path);
    Target target;
    int line_number = 0;
    size_t pos = 0;
    while (pos < text.size()) {
      size_t end = text.find('\n', pos);
      if (end == std::string::npos) end = text.size();
      const std::string_view line(text.data() + pos, end - pos);
      pos = end + 1;
      ++line_number;
      const std::vector<std::string_view> tokens = SplitWhitespace(line);
      if (tokens.empty() || tokens[0][0] == '#') continue;
      const std::string where =
          fmt::format("{}:{}", path.string(), line_number);
      if (tokens.size() != 4) {
        throw IoError(
            fmt::format("{}: expected 'vertex dx dy dz', got {} fields",
                        where,
                        tokens.size()));
      }
      const long index = ParseInteger(tokens[0], where);
      if (index < 0 || index >= num_vertices_) {
        throw IoError(fmt::format("{}: vertex {} outside the {} mesh vertices",
                                  where,
                                  index,
                                  num_vertices_));
      }
      target.indices.push_back(static_cast<int>(index));
      target.offsets.push_back(ToOurs(ParseDouble(tokens[1], where),
                                      ParseDouble(tokens[2], where),
                                      ParseDouble(tokens[3], where),
                                      scale_));
    }
    loaded_.push_back(name);
    return cache_.emplace(name, std::move(target)).first->second;
  }

  const std::vector<std::string>& loaded() const { return loaded_; }

 private:
  std::filesystem::path dir_;
  int num_vertices_;
  double scale_;
  std::map<std::string, Target> cache_;
  std::vector<std::string> loaded_;
};

/// MakeHuman macro sliders (all in [0, 1]; race weights sum to 1).
struct MacroSettings {
  double gender = 0.5;  // 0 female, 1 male
  double age =
      0.5;  // 0 baby (1 year), 0.1875 child (11), 0.5 young (25), 1 old (90)
  double muscle = 0.5;
  double weight = 0.5;
  std::array<double, 3> race = {
      1.0 / 3, 1.0 / 3, 1.0 / 3};  // african, asian, caucasian
};

using NamedWeights = std::vector<std::pair<std::string, double>>;

NamedWeights GenderWeights(double g) {
  return {{"female", 1.0 - g}, {"male", g}};
}

NamedWeights AgeWeights(double a) {
  if (a < 0.1875) return {{"baby", 1.0 - a / 0.1875}, {"child", a / 0.1875}};
  if (a < 0.5) {
    const double t = (a - 0.1875) / (0.5 - 0.1875);
    return {{"child", 1.0 - t}, {"young", t}};
  }
  const double t = (a - 0.5) / 0.5;
  return {{"young", 1.0 - t}, {"old", t}};
}

// Piecewise linear min -> average -> max (muscle and weight sliders).
NamedWeights ThreeLevelWeights(double v, const std::string& suffix) {
  if (v < 0.5)
    return {{"min" + suffix, 1.0 - 2.0 * v}, {"average" + suffix, 2.0 * v}};
  return {{"average" + suffix, 2.0 - 2.0 * v}, {"max" + suffix, 2.0 * v - 1.0}};
}

/// Displacement of every mesh vertex (3 x N, ours) for the macro sliders.
Eigen::Matrix3Xd MacroDisplacement(const MacroSettings& s,
                                   TargetCache& cache,
                                   int num_vertices) {
  constexpr double kNegligible = 1e-12;
  Eigen::Matrix3Xd displacement = Eigen::Matrix3Xd::Zero(3, num_vertices);
  const auto add = [&](const std::string& name, double weight) {
    if (std::abs(weight) < kNegligible) return;
    const Target& target = cache.Get(name);
    for (size_t i = 0; i < target.indices.size(); ++i) {
      displacement.col(target.indices[i]) += weight * target.offsets[i];
    }
  };
  const NamedWeights genders = GenderWeights(s.gender);
  const NamedWeights ages = AgeWeights(s.age);
  const NamedWeights muscles = ThreeLevelWeights(s.muscle, "muscle");
  const NamedWeights weights = ThreeLevelWeights(s.weight, "weight");
  for (const auto& [gender, gw] : genders) {
    for (const auto& [age, aw] : ages) {
      for (const auto& [muscle, mw] : muscles) {
        for (const auto& [weight, ww] : weights) {
          add(fmt::format("universal-{}-{}-{}-{}", gender, age, muscle, weight),
              gw * aw * mw * ww);
        }
      }
      static const std::array<const char*, 3> kRaces = {
          "african", "asian", "caucasian"};
      for (int r = 0; r < 3; ++r) {
        add(fmt::format("{}-{}-{}", kRaces[r], gender, age),
            s.race[r] * gw * aw);
      }
    }
  }
  return displacement;
}

// ---------------------------------------------------------------------------
// Rig.

// A head or tail definition, evaluated on the full mesh.
struct PointDef {
  bool per_axis = false;     // XYZ strategy: indices[c] gives coordinate c
  std::vector<int> indices;  // mean of these vertices otherwise
};

struct RigBone {
  std::string name;
  std::string parent_name;
  int parent = -1;  // index in the topologically sorted bone list
  double roll = 0.0;
  PointDef head;
  PointDef tail;
};

Eigen::Vector3d Evaluate(const PointDef& def,
                         const Eigen::Matrix3Xd& vertices) {
  if (def.per_axis) {
    return Eigen::Vector3d(vertices(0, def.indices[0]),
                           vertices(1, def.indices[1]),
                           vertices(2, def.indices[2]));
  }
  Eigen::Vector3d sum = Eigen::Vector3d::Zero();
  for (const int i : def.indices) sum += vertices.col(i);
  return sum / static_cast<double>(def.indices.size());
}

PointDef ParsePointDef(const Json& json,
                       const std::map<std::string, std::vector<int>>& groups,
                       int num_vertices,
                       const std::string& where) {
  PointDef def;
  const std::string& strategy = JsonString(Member(json, "strategy", where));
  const auto check = [&](int64_t index) {
    if (index < 0 || index >= num_vertices) {
      throw IoError(fmt::format("{}: vertex {} outside the {} mesh vertices",
                                where,
                                index,
                                num_vertices));
    }
    return static_cast<int>(index);
  };
  if (strategy == "CUBE") {
    const std::string& cube = JsonString(Member(json, "cube_name", where));
    const auto it = groups.find(cube);
    if (it == groups.end() || it->second.empty()) {
      throw IoError(fmt::format(
          "{}: joint cube '{}' is not a vertex group of the base mesh",
          where,
          cube));
    }
    def.indices = it->second;
  } else if (strategy == "VERTEX") {
    def.indices = {check(JsonInt(Member(json, "vertex_index", where)))};
  } else if (strategy == "MEAN" || strategy == "XYZ") {
    for (const Json& index : JsonArray(Member(json, "vertex_indices", where))) {
      def.indices.push_back(check(JsonInt(index)));
    }
    def.per_axis = strategy == "XYZ";
    if (def.indices.empty() || (def.per_axis && def.indices.size() != 3)) {
      throw IoError(fmt::format("{}: strategy {} needs {} vertex indices",
                                where,
                                strategy,
                                def.per_axis ? "3" : "at least 1"));
    }
  } else {
    throw IoError(fmt::format(
        "{}: unknown strategy '{}' (expected CUBE, VERTEX, MEAN or XYZ)",
        where,
        strategy));
  }
  return def;
}

// Bones sorted so that parents come first.
std::vector<RigBone> ReadRig(
    const std::filesystem::path& path,
    const std::map<std::string, std::vector<int>>& groups,
    int num_vertices) {
  return WithFile(path, [&] {
    const Json root = ReadJsonFile(path);
    std::vector<RigBone> unsorted;
    for (const auto& [name, bone] : JsonObject(root)) {
      const std::string where = fmt::format("bone '{}'", name);
      RigBone b;
      b.name = name;
      b.parent_name = JsonString(Member(bone, "parent", where));
      b.roll = JsonNumber(Member(bone, "roll", where));
      b.head = ParsePointDef(
          Member(bone, "head", where), groups, num_vertices, where + " head");
      b.tail = ParsePointDef(
          Member(bone, "tail", where), groups, num_vertices, where + " tail");
      unsorted.push_back(std::move(b));
    }
    std::vector<RigBone> sorted;
    std::map<std::string, int> index;
    while (sorted.size() < unsorted.size()) {
      bool progress = false;
      for (RigBone& bone : unsorted) {
        if (index.count(bone.name)) continue;
        if (bone.parent_name.empty() || index.count(bone.parent_name)) {
          bone.parent =
              bone.parent_name.empty() ? -1 : index.at(bone.parent_name);
          index[bone.name] = static_cast<int>(sorted.size());
          sorted.push_back(bone);
          progress = true;
        }
      }
      if (!progress) {
        throw IoError("bones with unknown parents or a parent cycle");
      }
    }
    int roots = 0;
    for (const RigBone& bone : sorted) roots += bone.parent < 0 ? 1 : 0;
    if (roots != 1)
      throw IoError(fmt::format("expected one root bone, found {}", roots));
    return sorted;
  });
}

// bone -> (vertex, weight) lists.
std::map<std::string, std::vector<std::pair<int, double>>> ReadWeights(
    const std::filesystem::path& path, int num_vertices) {
  return WithFile(path, [&] {
    const Json root = ReadJsonFile(path);
    std::map<std::string, std::vector<std::pair<int, double>>> weights;
    for (const auto& [bone, list] :
         JsonObject(Member(root, "weights", "the file"))) {
      auto& out = weights[bone];
      for (const Json& entry : JsonArray(list)) {
        const Json::array_t& pair = JsonArray(entry);
        if (pair.size() != 2) {
          throw IoError(
              fmt::format("bone '{}': entries must be [vertex, weight]", bone));
        }
        const int64_t vertex = JsonInt(pair[0]);
        const double weight = JsonNumber(pair[1]);
        if (vertex < 0 || vertex >= num_vertices || !(weight >= 0.0) ||
            !std::isfinite(weight)) {
          throw IoError(fmt::format(
              "bone '{}': bad entry [{}, {}] (vertex in [0, {}), weight >= 0)",
              bone,
              vertex,
              weight,
              num_vertices));
        }
        out.emplace_back(static_cast<int>(vertex), weight);
      }
    }
    return weights;
  });
}

// bone -> Blender XYZ Euler angles (radians).
std::map<std::string, Eigen::Vector3d> ReadPose(
    const std::filesystem::path& path) {
  return WithFile(path, [&] {
    const Json root = ReadJsonFile(path);
    std::map<std::string, Eigen::Vector3d> rotations;
    for (const auto& [bone, angles] :
         JsonObject(Member(root, "bone_rotations", "the file"))) {
      const Json::array_t& xyz = JsonArray(angles);
      if (xyz.size() != 3) {
        throw IoError(
            fmt::format("bone '{}': rotation must be 3 Euler angles", bone));
      }
      rotations[bone] = Eigen::Vector3d(
          JsonNumber(xyz[0]), JsonNumber(xyz[1]), JsonNumber(xyz[2]));
    }
    if (const Json* translations = JsonFind(root, "bone_translations");
        translations != nullptr && translations->size() > 0) {
      throw IoError("bone_translations are not supported");
    }
    return rotations;
  });
}

/// Blender's bone rest frame (vec_roll_to_mat3_normalized): the rotation
/// taking +Y to the bone direction `dir` by the shortest arc, then a roll
/// about `dir`.
Eigen::Matrix3d BoneFrame(const Eigen::Vector3d& dir, double roll) {
  const double x = dir.x();
  const double y = dir.y();
  const double z = dir.z();
  const double theta = 1.0 + y;
  const double theta_alt = x * x + z * z;
  Eigen::Matrix3d b;
  if (theta > 1e-5 || ((x != 0.0 || z != 0.0) && theta > 1e-9)) {
    const double t =
        theta > 1e-5 ? theta : theta_alt * 0.5 + theta_alt * theta_alt * 0.125;
    b << 1.0 - x * x / t, x, -x * z / t,  //
        -x, y, -z,                        //
        -x * z / t, z, 1.0 - z * z / t;
  } else {
    b = Eigen::Vector3d(-1.0, -1.0, 1.0).asDiagonal();
  }
  return Eigen::AngleAxisd(roll, dir).toRotationMatrix() * b;
}

/// Blender Euler 'XYZ': R = Rz Ry Rx.
Eigen::Matrix3d EulerXyz(const Eigen::Vector3d& angles) {
  return (Eigen::AngleAxisd(angles.z(), Eigen::Vector3d::UnitZ()) *
          Eigen::AngleAxisd(angles.y(), Eigen::Vector3d::UnitY()) *
          Eigen::AngleAxisd(angles.x(), Eigen::Vector3d::UnitX()))
      .toRotationMatrix();
}

struct RigState {
  std::vector<Eigen::Vector3d> heads;  // per bone, posed
  Eigen::Matrix3Xd body;               // posed body vertices (3 x num_body)
};

/// Poses the full mesh `vertices` with `euler` (bone -> Blender XYZ Euler
/// angles; an empty map keeps the rest pose) and returns the posed bone heads
/// and body vertices. Bone heads/tails are evaluated on `vertices`, so the rig
/// follows the shape.
RigState PoseRig(
    const std::vector<RigBone>& bones,
    const Eigen::Matrix3Xd& vertices,
    int num_body,
    const std::map<std::string, Eigen::Vector3d>& euler,
    const std::vector<std::vector<std::pair<int, double>>>& weights_by_bone) {
  const size_t count = bones.size();
  std::vector<Eigen::Isometry3d> skinning(count);
  RigState state;
  state.heads.resize(count);
  for (size_t b = 0; b < count; ++b) {
    const Eigen::Vector3d head = Evaluate(bones[b].head, vertices);
    Eigen::Isometry3d local = Eigen::Isometry3d::Identity();
    const auto it = euler.find(bones[b].name);
    if (it != euler.end()) {
      const Eigen::Vector3d tail = Evaluate(bones[b].tail, vertices);
      const Eigen::Vector3d axis = tail - head;
      if (axis.norm() < 1e-9) {
        throw IoError(fmt::format("MakeHuman rig: bone '{}' has zero length",
                                  bones[b].name));
      }
      const Eigen::Matrix3d frame = BoneFrame(axis.normalized(), bones[b].roll);
      const Eigen::Matrix3d world =
          frame * EulerXyz(it->second) * frame.transpose();
      local.linear() = world;
      local.translation() = head - world * head;
    }
    skinning[b] =
        bones[b].parent < 0 ? local : skinning[bones[b].parent] * local;
    state.heads[b] = skinning[b] * head;
  }
  if (euler.empty()) {
    state.body = vertices.leftCols(num_body);
    return state;
  }
  // Linear blend skinning of the body vertices with the full rig.
  std::vector<Eigen::Matrix<double, 3, 4>> blended(
      num_body, Eigen::Matrix<double, 3, 4>::Zero());
  std::vector<double> total(num_body, 0.0);
  for (size_t b = 0; b < count; ++b) {
    const Eigen::Matrix<double, 3, 4> m = skinning[b].matrix().topRows<3>();
    for (const auto& [v, w] : weights_by_bone[b]) {
      if (v >= num_body) continue;
      blended[v] += w * m;
      total[v] += w;
    }
  }
  state.body.resize(3, num_body);
  for (int v = 0; v < num_body; ++v) {
    state.body.col(v) =
        (blended[v].leftCols<3>() * vertices.col(v) + blended[v].col(3)) /
        total[v];
  }
  return state;
}

// ---------------------------------------------------------------------------
// Joint map.

const std::vector<MakeHumanJointSource>& JointMap() {
  static const std::vector<MakeHumanJointSource>* const kMap =
      new std::vector<MakeHumanJointSource>{
          {"pelvis", "Hips"},
          {"left_hip", "LeftUpLeg"},
          {"right_hip", "RightUpLeg"},
          {"spine1", "LowerBack"},
          {"left_knee", "LeftLeg"},
          {"right_knee", "RightLeg"},
          {"spine2", "Spine"},
          {"left_ankle", "LeftFoot"},
          {"right_ankle", "RightFoot"},
          {"spine3", "Spine1"},
          {"left_foot", "LeftToeBase"},
          {"right_foot", "RightToeBase"},
          {"neck", "Neck"},
          {"left_collar", "LeftShoulder"},
          {"right_collar", "RightShoulder"},
          {"head", "Head"},
          {"left_shoulder", "LeftArm"},
          {"right_shoulder", "RightArm"},
          {"left_elbow", "LeftForeArm"},
          {"right_elbow", "RightForeArm"},
          {"left_wrist", "LeftHand"},
          {"right_wrist", "RightHand"},
          {"left_hand", "LeftFingerBase"},
          {"right_hand", "RightFingerBase"},
          {"left_thumb", "LThumb"},
          {"left_fingers", "LeftHandFinger1"},
          {"right_thumb", "RThumb"},
          {"right_fingers", "RightHandFinger1"},
      };
  return *kMap;
}

// ---------------------------------------------------------------------------
// Regressor fit.

struct RegressorFit {
  std::vector<std::pair<int, double>> weights;
  double residual = 0.0;  // metres
};

/// Fits affine weights over body vertices near `joint` that reproduce the
/// joint for the mean shape (`vertices`) and its displacement `joint_deltas`
/// for every shape direction (`dirs`, 3V x B).
RegressorFit FitJointRegressor(const Eigen::Vector3d& joint,
                               const Eigen::Matrix3Xd& joint_deltas,
                               const Eigen::Matrix3Xd& vertices,
                               const Eigen::MatrixXd& dirs,
                               double support_factor) {
  const int num_vertices = static_cast<int>(vertices.cols());
  const int num_dirs = static_cast<int>(dirs.cols());
  std::vector<std::pair<double, int>> by_distance(num_vertices);
  for (int v = 0; v < num_vertices; ++v)
    by_distance[v] = {(vertices.col(v) - joint).norm(), v};
  const int keep_max = std::min(kMaxSupport, num_vertices);
  std::partial_sort(
      by_distance.begin(), by_distance.begin() + keep_max, by_distance.end());
  const double radius = std::max(support_factor * by_distance[0].first,
                                 by_distance[0].first + 1e-3);
  int support = 0;
  while (support < keep_max &&
         (support < kMinSupport || by_distance[support].first <= radius)) {
    ++support;
  }
  // Constraint rows: sum = 1; position (relative to the joint) = 0; each
  // direction's displacement = the joint's displacement.
  const int rows = 1 + 3 + 3 * num_dirs;
  Eigen::MatrixXd a(rows, support);
  Eigen::VectorXd b = Eigen::VectorXd::Zero(rows);
  for (int k = 0; k < support; ++k) {
    const int v = by_distance[k].second;
    a(0, k) = 1.0;
    a.block<3, 1>(1, k) = vertices.col(v) - joint;
    for (int d = 0; d < num_dirs; ++d)
      a.block<3, 1>(4 + 3 * d, k) =
          dirs.block<3, 1>(3 * static_cast<Eigen::Index>(v), d);
  }
  b(0) = 1.0;
  for (int d = 0; d < num_dirs; ++d)
    b.segment<3>(4 + 3 * d) = joint_deltas.col(d);
  const Eigen::MatrixXd a_raw = a;
  const Eigen::VectorXd b_raw = b;
  for (int r = 0; r < rows; ++r) {
    const double norm = a.row(r).norm();
    if (norm > 1e-12) {
      a.row(r) /= norm;
      b(r) /= norm;
    } else {
      a.row(r).setZero();
      b(r) = 0.0;
    }
  }
  const Eigen::VectorXd w0 = Eigen::VectorXd::Constant(support, 1.0 / support);
  Eigen::MatrixXd gram = a * a.transpose();
  gram.diagonal().array() += kRegressorRidge;
  const Eigen::VectorXd y = gram.ldlt().solve(b - a * w0);
  const Eigen::VectorXd w = w0 + a.transpose() * y;

  RegressorFit fit;
  const Eigen::VectorXd error = a_raw * w - b_raw;
  fit.residual = error.segment<3>(1).norm();
  for (int d = 0; d < num_dirs; ++d) {
    fit.residual = std::max(fit.residual, error.segment<3>(4 + 3 * d).norm());
  }
  for (int k = 0; k < support; ++k) {
    if (std::abs(w(k)) > kRegressorDropTolerance)
      fit.weights.emplace_back(by_distance[k].second, w(k));
  }
  return fit;
}

// ---------------------------------------------------------------------------
// Anthropometric proportions.

struct ProportionCorrection {
  Eigen::Matrix3Xd vertex_displacement;  // 3 x V
  Eigen::Matrix3Xd joint_displacement;   // 3 x J
};

/// Lengthens (or shortens) both upper arms of the rest template `vertices`
/// with joints `joints` to `upper_arm_length` (see the file comment of
/// makehuman_body.h): the elbow and its descendants move rigidly by the
/// stretch s along shoulder -> elbow; a vertex moves by sum_j w_vj d_j with
/// d_shoulder = t_v s (t_v: clamped normalised projection on the bone),
/// d_j = s for the elbow and its descendants, 0 otherwise.
ProportionCorrection UpperArmCorrection(const Eigen::Matrix3Xd& vertices,
                                        const Eigen::Matrix3Xd& joints,
                                        const std::vector<int>& parents,
                                        const SparseRowMatrix& weights,
                                        double upper_arm_length) {
  const int num_vertices = static_cast<int>(vertices.cols());
  const int num_joints = static_cast<int>(joints.cols());
  ProportionCorrection out;
  out.vertex_displacement = Eigen::Matrix3Xd::Zero(3, num_vertices);
  out.joint_displacement = Eigen::Matrix3Xd::Zero(3, num_joints);
  for (const auto& [shoulder, elbow] :
       {std::pair<int, int>{kLeftShoulder, kLeftElbow},
        std::pair<int, int>{kRightShoulder, kRightElbow}}) {
    const Eigen::Vector3d origin = joints.col(shoulder);
    const Eigen::Vector3d bone = joints.col(elbow) - origin;
    const double length = bone.norm();
    if (!(length > 1e-6)) {
      throw IoError(fmt::format(
          "MakeHuman body: joints '{}' and '{}' coincide, cannot correct the "
          "upper arm",
          JointMap()[shoulder].joint,
          JointMap()[elbow].joint));
    }
    const Eigen::Vector3d stretch = (upper_arm_length - length) / length * bone;
    // The elbow and everything below it (parents come first).
    std::vector<char> below(num_joints, 0);
    below[elbow] = 1;
    for (int j = elbow + 1; j < num_joints; ++j) {
      if (parents[j] >= 0 && below[parents[j]]) below[j] = 1;
    }
    for (int j = 0; j < num_joints; ++j) {
      if (below[j]) out.joint_displacement.col(j) += stretch;
    }
    for (int v = 0; v < num_vertices; ++v) {
      double factor = 0.0;
      for (SparseRowMatrix::InnerIterator it(weights, v); it; ++it) {
        const int j = static_cast<int>(it.col());
        if (below[j]) {
          factor += it.value();
        } else if (j == shoulder) {
          const double t = std::clamp(
              (vertices.col(v) - origin).dot(bone) / (length * length),
              0.0,
              1.0);
          factor += it.value() * t;
        }
      }
      if (factor != 0.0) out.vertex_displacement.col(v) += factor * stretch;
    }
  }
  return out;
}

}  // namespace

void MakeHumanLoadOptions::Validate() const {
  const int max_betas = static_cast<int>(MakeHumanShapeComponentNames().size());
  if (num_betas < 0 || num_betas > max_betas) {
    throw ConfigError(
        fmt::format("Invalid configuration. num_betas = {}. Violated "
                    "constraint: 0 <= num_betas <= {} "
                    "(makehuman_body.h)",
                    num_betas,
                    max_betas));
  }
  if (!(metres_per_unit > 0.0) || !std::isfinite(metres_per_unit)) {
    throw ConfigError(
        fmt::format("Invalid configuration. metres_per_unit = {}. Violated "
                    "constraint: metres_per_unit > 0 "
                    "(makehuman_body.h)",
                    metres_per_unit));
  }
  if (!(regressor_support_factor >= 1.0) ||
      !std::isfinite(regressor_support_factor)) {
    throw ConfigError(
        fmt::format("Invalid configuration. regressor_support_factor = {}. "
                    "Violated constraint: "
                    "regressor_support_factor >= 1 (makehuman_body.h)",
                    regressor_support_factor));
  }
  if (!(upper_arm_ratio > 0.0 && upper_arm_ratio < 0.5)) {
    throw ConfigError(
        fmt::format("Invalid configuration. upper_arm_ratio = {}. Violated "
                    "constraint: 0 < upper_arm_ratio < 0.5 (makehuman_body.h)",
                    upper_arm_ratio));
  }
}

const std::vector<std::string>& MakeHumanShapeComponentNames() {
  static const std::vector<std::string>* const kNames =
      new std::vector<std::string>{
          "stature", "gender", "weight", "muscle", "age", "african", "asian"};
  return *kNames;
}

const std::vector<MakeHumanJointSource>& MakeHumanJointMap() {
  return JointMap();
}

const std::vector<MakeHumanDroppedBone>& MakeHumanDroppedBones() {
  static const std::vector<MakeHumanDroppedBone>* const kDropped =
      new std::vector<MakeHumanDroppedBone>{
          {"LHipJoint", "Hips"}, {"RHipJoint", "Hips"}, {"Neck1", "Neck"}};
  return *kDropped;
}

BodyModel LoadMakeHumanBody(const std::filesystem::path& dir,
                            const MakeHumanLoadOptions& options,
                            MakeHumanLoadReport* report) {
  options.Validate();
  if (!std::filesystem::is_directory(dir)) {
    throw IoError(
        fmt::format("MakeHuman body: missing directory '{}'", dir.string()));
  }
  const bool t_pose =
      options.rest_pose == MakeHumanLoadOptions::RestPose::kTPose;
  const std::filesystem::path obj_path = RequireFile(dir, kObjFile);
  const std::filesystem::path groups_path = RequireFile(dir, kGroupsFile);
  const std::filesystem::path rig_path = RequireFile(dir, kRigFile);
  const std::filesystem::path weights_path = RequireFile(dir, kWeightsFile);
  if (!std::filesystem::is_directory(dir / kTargetsDir)) {
    throw IoError(fmt::format("MakeHuman body: missing directory '{}'",
                              (dir / kTargetsDir).string()));
  }
  std::map<std::string, Eigen::Vector3d> t_pose_angles;
  if (t_pose) t_pose_angles = ReadPose(RequireFile(dir, kTPoseFile));

  // ---- Mesh: keep the vertices of the body group.
  const ObjMesh obj = ReadObj(obj_path, options.metres_per_unit);
  const int num_all = static_cast<int>(obj.vertices.cols());
  int num_body = 0;
  for (const auto& face : obj.body_faces) {
    for (const int v : face) num_body = std::max(num_body, v + 1);
  }
  // The body group is a prefix of the vertex list (hm08: 0..13379); the
  // helpers and joint cubes follow.
  std::vector<char> used(num_body, 0);
  for (const auto& face : obj.body_faces) {
    for (const int v : face) used[v] = 1;
  }
  if (std::find(used.begin(), used.end(), 0) != used.end()) {
    throw IoError(fmt::format(
        "{}: the '{}' group does not use a contiguous vertex prefix",
        obj_path.string(),
        kBodyGroup));
  }

  const auto groups = ReadVertexGroups(groups_path, num_all);
  const std::vector<RigBone> bones = ReadRig(rig_path, groups, num_all);
  const auto weights_json = ReadWeights(weights_path, num_all);
  std::map<std::string, int> bone_index;
  for (size_t b = 0; b < bones.size(); ++b)
    bone_index[bones[b].name] = static_cast<int>(b);
  for (const auto& [bone, unused] : weights_json) {
    if (!bone_index.count(bone)) {
      throw IoError(fmt::format("{}: weights for bone '{}', which is not in {}",
                                weights_path.string(),
                                bone,
                                rig_path.string()));
    }
  }
  for (const auto& [bone, unused] : t_pose_angles) {
    if (!bone_index.count(bone)) {
      throw IoError(
          fmt::format("{}: rotation for bone '{}', which is not in {}",
                      (dir / kTPoseFile).string(),
                      bone,
                      rig_path.string()));
    }
  }
  std::vector<std::vector<std::pair<int, double>>> weights_by_bone(
      bones.size());
  for (const auto& [bone, list] : weights_json)
    weights_by_bone[bone_index.at(bone)] = list;

  // ---- Mean shape and shape components on the full mesh (asset pose).
  TargetCache targets(dir / kTargetsDir, num_all, options.metres_per_unit);
  const MacroSettings mean_settings;
  const Eigen::Matrix3Xd mean_displacement =
      MacroDisplacement(mean_settings, targets, num_all);
  const Eigen::Matrix3Xd mean_full = obj.vertices + mean_displacement;
  const int num_betas = options.num_betas;
  std::vector<Eigen::Matrix3Xd> components;
  const auto macro = [&](const MacroSettings& s) {
    return MacroDisplacement(s, targets, num_all);
  };
  for (int k = 0; k < num_betas; ++k) {
    const std::string& name = MakeHumanShapeComponentNames()[k];
    MacroSettings lo = mean_settings;
    MacroSettings hi = mean_settings;
    double factor = 1.0;
    if (name == "stature") {
      const Eigen::Matrix3Xd body = mean_full.leftCols(num_body);
      const Eigen::Vector3d pivot(
          body.row(0).mean(), body.row(1).mean(), body.row(2).minCoeff());
      components.push_back(kStatureScalePerBeta *
                           (mean_full.colwise() - pivot));
      continue;
    }
    if (name == "gender") {
      lo.gender = 0.0;
      hi.gender = 1.0;
      factor = 0.5;
    } else if (name == "weight") {
      lo.weight = 0.0;
      hi.weight = 1.0;
      factor = 0.25;
    } else if (name == "muscle") {
      lo.muscle = 0.0;
      hi.muscle = 1.0;
      factor = 0.25;
    } else if (name == "age") {
      hi.age = 1.0;
      factor = 0.5;
    } else if (name == "african") {
      hi.race = {1.0, 0.0, 0.0};
      factor = 0.5;
    } else if (name == "asian") {
      hi.race = {0.0, 1.0, 0.0};
      factor = 0.5;
    }
    components.push_back(factor * (macro(hi) - macro(lo)));
  }

  // ---- Rest pose (T-pose or asset) of the mean and of mean + component.
  const auto kept_joints = [&](const RigState& state) {
    Eigen::Matrix3Xd joints(3, JointMap().size());
    for (size_t j = 0; j < JointMap().size(); ++j) {
      const auto it = bone_index.find(JointMap()[j].bone);
      if (it == bone_index.end()) {
        throw IoError(fmt::format("{}: bone '{}' (for joint '{}') is missing",
                                  rig_path.string(),
                                  JointMap()[j].bone,
                                  JointMap()[j].joint));
      }
      joints.col(j) = state.heads[it->second];
    }
    return joints;
  };
  const RigState mean_state =
      PoseRig(bones, mean_full, num_body, t_pose_angles, weights_by_bone);
  const Eigen::Matrix3Xd mean_joints = kept_joints(mean_state);
  const double floor = mean_state.body.row(2).minCoeff();
  BodyModel body;
  body.name = "makehuman";
  body.template_vertices = mean_state.body;
  body.template_vertices.row(2).array() -= floor;
  Eigen::Matrix3Xd joints_rest = mean_joints;
  joints_rest.row(2).array() -= floor;
  body.shape_dirs.resize(3 * static_cast<Eigen::Index>(num_body), num_betas);
  Eigen::Matrix3Xd joint_deltas_all(
      3, static_cast<Eigen::Index>(JointMap().size()) * num_betas);
  for (int k = 0; k < num_betas; ++k) {
    const RigState state = PoseRig(bones,
                                   mean_full + components[k],
                                   num_body,
                                   t_pose_angles,
                                   weights_by_bone);
    const Eigen::Matrix3Xd delta = state.body - mean_state.body;
    body.shape_dirs.col(k) =
        Eigen::Map<const Eigen::VectorXd>(delta.data(), delta.size());
    joint_deltas_all.middleCols(k * JointMap().size(), JointMap().size()) =
        kept_joints(state) - mean_joints;
  }
  body.beta_stddev = Eigen::VectorXd::Ones(num_betas);

  // ---- Faces (fan triangulation; flip if the OBJ winding is clockwise).
  std::vector<std::array<int, 3>> triangles;
  for (const auto& face : obj.body_faces) {
    for (size_t k = 1; k + 1 < face.size(); ++k)
      triangles.push_back({face[0], face[k], face[k + 1]});
  }
  double signed_volume = 0.0;
  for (const auto& t : triangles) {
    signed_volume += body.template_vertices.col(t[0]).dot(
        body.template_vertices.col(t[1]).cross(
            body.template_vertices.col(t[2])));
  }
  const bool flip = signed_volume < 0.0;
  body.faces.resize(3, static_cast<Eigen::Index>(triangles.size()));
  for (size_t f = 0; f < triangles.size(); ++f) {
    body.faces(0, f) = triangles[f][0];
    body.faces(1, f) = flip ? triangles[f][2] : triangles[f][1];
    body.faces(2, f) = flip ? triangles[f][1] : triangles[f][2];
  }

  // ---- Skeleton: kept joints, parents through dropped bones.
  const int num_joints = static_cast<int>(JointMap().size());
  std::vector<int> joint_of_bone(bones.size(), -1);
  for (int j = 0; j < num_joints; ++j)
    joint_of_bone[bone_index.at(JointMap()[j].bone)] = j;
  // Dropped bones hand their weights to the nearest kept ancestor.
  std::vector<int> receiver(bones.size(), -1);
  for (size_t b = 0; b < bones.size(); ++b) {
    int a = static_cast<int>(b);
    while (a >= 0 && joint_of_bone[a] < 0) a = bones[a].parent;
    if (a < 0) {
      throw IoError(fmt::format("{}: bone '{}' has no kept ancestor",
                                rig_path.string(),
                                bones[b].name));
    }
    receiver[b] = joint_of_bone[a];
  }
  for (int j = 0; j < num_joints; ++j) {
    body.joint_names.push_back(JointMap()[j].joint);
    const int parent_bone = bones[bone_index.at(JointMap()[j].bone)].parent;
    body.parents.push_back(parent_bone < 0 ? -1 : receiver[parent_bone]);
  }

  // ---- Skinning weights.
  Eigen::MatrixXd dense_weights = Eigen::MatrixXd::Zero(num_body, num_joints);
  for (size_t b = 0; b < bones.size(); ++b) {
    for (const auto& [v, w] : weights_by_bone[b]) {
      if (v < num_body) dense_weights(v, receiver[b]) += w;
    }
  }
  // The asset has a few stray weights across the midline (e.g. right toe
  // vertices with 0.2 % on LeftToeBase): drop weights of left/right joints
  // on vertices more than kMidlineMargin on the other side.
  std::vector<int> joint_side(num_joints, 0);
  for (int j = 0; j < num_joints; ++j) {
    const std::string& name = JointMap()[j].joint;
    joint_side[j] = name.rfind("left_", 0) == 0    ? 1
                    : name.rfind("right_", 0) == 0 ? -1
                                                   : 0;
  }
  int cross_side_removed = 0;
  for (int v = 0; v < num_body; ++v) {
    const double x = body.template_vertices(0, v);
    for (int j = 0; j < num_joints; ++j) {
      if (dense_weights(v, j) > 0.0 && joint_side[j] * x < -kMidlineMargin) {
        dense_weights(v, j) = 0.0;
        ++cross_side_removed;
      }
    }
  }
  std::vector<Eigen::Triplet<double>> triplets;
  for (int v = 0; v < num_body; ++v) {
    const double sum = dense_weights.row(v).sum();
    if (!(sum > 0.0)) {
      throw IoError(fmt::format("{}: body vertex {} has no skinning weight",
                                weights_path.string(),
                                v));
    }
    for (int j = 0; j < num_joints; ++j) {
      if (dense_weights(v, j) > 0.0)
        triplets.emplace_back(v, j, dense_weights(v, j) / sum);
    }
  }
  body.skinning_weights.resize(num_body, num_joints);
  body.skinning_weights.setFromTriplets(triplets.begin(), triplets.end());
  body.skinning_weights.makeCompressed();

  // ---- Anthropometric proportions: lengthen the upper arms (see the file
  // comment of makehuman_body.h). The stature direction is a uniform scaling
  // about the floor centre, 0.04 x (template - pivot), so it scales the
  // correction too; the other directions are deltas and stay.
  const auto arm_lengths = [](const Eigen::Matrix3Xd& joints) {
    return std::pair<double, double>(
        (joints.col(kLeftElbow) - joints.col(kLeftShoulder)).norm(),
        (joints.col(kLeftWrist) - joints.col(kLeftElbow)).norm());
  };
  const auto [asset_upper_arm, asset_forearm] = arm_lengths(joints_rest);
  if (options.proportions ==
      MakeHumanLoadOptions::Proportions::kAnthropometric) {
    const double stature = body.template_vertices.row(2).maxCoeff() -
                           body.template_vertices.row(2).minCoeff();
    const ProportionCorrection correction =
        UpperArmCorrection(body.template_vertices,
                           joints_rest,
                           body.parents,
                           body.skinning_weights,
                           options.upper_arm_ratio * stature);
    body.template_vertices += correction.vertex_displacement;
    joints_rest += correction.joint_displacement;
    for (int k = 0; k < num_betas; ++k) {
      if (MakeHumanShapeComponentNames()[k] != "stature") continue;
      body.shape_dirs.col(k) +=
          kStatureScalePerBeta * Eigen::Map<const Eigen::VectorXd>(
                                     correction.vertex_displacement.data(),
                                     correction.vertex_displacement.size());
      joint_deltas_all.middleCols(k * num_joints, num_joints) +=
          kStatureScalePerBeta * correction.joint_displacement;
    }
  }
  const auto [upper_arm, forearm] = arm_lengths(joints_rest);

  // ---- Joint regressor fitted on the (posed, shifted) mean and components.
  triplets.clear();
  double max_residual = 0.0;
  double max_weight = 0.0;
  for (int j = 0; j < num_joints; ++j) {
    Eigen::Matrix3Xd deltas(3, num_betas);
    for (int k = 0; k < num_betas; ++k)
      deltas.col(k) = joint_deltas_all.col(k * num_joints + j);
    const RegressorFit fit =
        FitJointRegressor(joints_rest.col(j),
                          deltas,
                          body.template_vertices,
                          body.shape_dirs,
                          options.regressor_support_factor);
    max_residual = std::max(max_residual, fit.residual);
    for (const auto& [v, w] : fit.weights) {
      triplets.emplace_back(j, v, w);
      max_weight = std::max(max_weight, std::abs(w));
    }
  }
  body.joint_regressor.resize(num_joints, num_body);
  body.joint_regressor.setFromTriplets(triplets.begin(), triplets.end());
  body.joint_regressor.makeCompressed();

  body.Validate();
  if (report != nullptr) {
    report->num_obj_vertices = num_all;
    report->num_body_vertices = num_body;
    report->num_body_quads = static_cast<int>(obj.body_faces.size());
    report->faces_flipped = flip;
    report->cross_side_weights_removed = cross_side_removed;
    report->stature_m = body.template_vertices.row(2).maxCoeff() -
                        body.template_vertices.row(2).minCoeff();
    report->targets_loaded = targets.loaded();
    report->max_regressor_residual_m = max_residual;
    report->max_abs_regressor_weight = max_weight;
    report->regressor_nonzeros =
        static_cast<int>(body.joint_regressor.nonZeros());
    report->asset_upper_arm_m = asset_upper_arm;
    report->upper_arm_m = upper_arm;
    report->asset_forearm_m = asset_forearm;
    report->forearm_m = forearm;
  }
  return body;
}

}  // namespace soma
