#include "framework/body/smpl_body.h"

#include "framework/core/error.h"
#include "framework/io/npz.h"

#include <Eigen/SparseCore>
#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <limits>
#include <vector>

namespace soma {
namespace {

using SparseRowMatrix = Eigen::SparseMatrix<double, Eigen::RowMajor>;

constexpr int kSmplJoints = 24;
constexpr int kSmplHJoints = 52;
constexpr int kSmplXJoints = 55;
constexpr int kBodyJoints = 22;  // SMPL body joints shared by the family
// J_regressor rows are affine combinations (sum 1); a row far from that is
// not a joint regressor.
constexpr double kRegressorRowSumTolerance = 0.05;

const std::vector<std::string>& HandJointNames() {
  static const std::vector<std::string>* const kNames =
      new std::vector<std::string>{
          "left_index1",   "left_index2",  "left_index3",   "left_middle1",
          "left_middle2",  "left_middle3", "left_pinky1",   "left_pinky2",
          "left_pinky3",   "left_ring1",   "left_ring2",    "left_ring3",
          "left_thumb1",   "left_thumb2",  "left_thumb3",   "right_index1",
          "right_index2",  "right_index3", "right_middle1", "right_middle2",
          "right_middle3", "right_pinky1", "right_pinky2",  "right_pinky3",
          "right_ring1",   "right_ring2",  "right_ring3",   "right_thumb1",
          "right_thumb2",  "right_thumb3"};
  return *kNames;
}

// A loaded array with its key, for shape checks with readable messages.
struct Keyed {
  std::string key;
  NpyArray array;
};

Keyed ReadKey(const NpzReader& reader, const std::string& key) {
  if (!reader.Contains(key)) {
    throw IoError(fmt::format(
        "{}: missing key '{}' (an SMPL-family model needs v_template, f, "
        "shapedirs, posedirs, J_regressor, weights, kintree_table)",
        reader.path().string(),
        key));
  }
  return {key, reader.Read(key)};
}

// Throws IoError unless the array has exactly the `expected` dims (-1 = any
// size) and a numeric dtype; `expected_text` describes the expectation.
void RequireShape(const NpzReader& reader,
                  const Keyed& keyed,
                  const std::vector<int64_t>& expected,
                  const std::string& expected_text) {
  bool ok = keyed.array.shape.size() == expected.size();
  for (size_t i = 0; ok && i < expected.size(); ++i) {
    if (expected[i] >= 0 && keyed.array.shape[i] != expected[i]) ok = false;
  }
  if (!ok) {
    throw IoError(fmt::format("{}: '{}' has shape {}, expected {}",
                              reader.path().string(),
                              keyed.key,
                              keyed.array.ShapeString(),
                              expected_text));
  }
  if (keyed.array.kind() == 'U' || keyed.array.kind() == 'S') {
    throw IoError(
        fmt::format("{}: '{}' is a string array ('{}'), expected numbers",
                    reader.path().string(),
                    keyed.key,
                    keyed.array.dtype));
  }
}

std::vector<double> FiniteDoubles(const NpzReader& reader, const Keyed& keyed) {
  std::vector<double> values = keyed.array.AsDoubles();
  for (const double v : values) {
    if (!std::isfinite(v)) {
      throw IoError(fmt::format(
          "{}: '{}' contains NaN or Inf", reader.path().string(), keyed.key));
    }
  }
  return values;
}

// K[3a+b, 3c+d] = C[c, a] C[d, b]: vec(C^T X C) = K vec(X), row-major vec.
Eigen::Matrix<double, 9, 9> PoseFeatureMap(const Eigen::Matrix3d& c) {
  Eigen::Matrix<double, 9, 9> k;
  for (int a = 0; a < 3; ++a) {
    for (int b = 0; b < 3; ++b) {
      for (int cc = 0; cc < 3; ++cc) {
        for (int d = 0; d < 3; ++d)
          k(3 * a + b, 3 * cc + d) = c(cc, a) * c(d, b);
      }
    }
  }
  return k;
}

}  // namespace

const char* ToString(SmplFamily family) {
  switch (family) {
    case SmplFamily::kSmpl:
      return "smpl";
    case SmplFamily::kSmplH:
      return "smplh";
    case SmplFamily::kSmplX:
      return "smplx";
  }
  return "smpl";
}

void SmplLoadOptions::Validate() const {
  if (num_betas < 0) {
    throw ConfigError(
        fmt::format("Invalid configuration. num_betas = {}. Violated "
                    "constraint: num_betas >= 0 (smpl_body.h)",
                    num_betas));
  }
  if (!std::isfinite(sparsity_threshold) || sparsity_threshold < 0.0) {
    throw ConfigError(fmt::format(
        "Invalid configuration. sparsity_threshold = {}. Violated constraint: "
        "sparsity_threshold >= 0 (smpl_body.h)",
        sparsity_threshold));
  }
}

Eigen::Matrix3d SmplToBodyFrame() {
  Eigen::Matrix3d c;
  c << 1, 0, 0, 0, 0, -1, 0, 1, 0;
  return c;
}

const std::vector<std::string>& SmplFileJointNames(SmplFamily family) {
  static const std::vector<std::string>* const kSmpl =
      new std::vector<std::string>(CoreJointNames());
  static const std::vector<std::string>* const kSmplH = [] {
    auto* names = new std::vector<std::string>(
        CoreJointNames().begin(), CoreJointNames().begin() + kBodyJoints);
    names->insert(
        names->end(), HandJointNames().begin(), HandJointNames().end());
    return names;
  }();
  static const std::vector<std::string>* const kSmplX = [] {
    auto* names = new std::vector<std::string>(
        CoreJointNames().begin(), CoreJointNames().begin() + kBodyJoints);
    names->insert(names->end(), {"jaw", "left_eye_smplhf", "right_eye_smplhf"});
    names->insert(
        names->end(), HandJointNames().begin(), HandJointNames().end());
    return names;
  }();
  switch (family) {
    case SmplFamily::kSmpl:
      return *kSmpl;
    case SmplFamily::kSmplH:
      return *kSmplH;
    case SmplFamily::kSmplX:
      return *kSmplX;
  }
  return *kSmpl;
}

std::vector<int> SmplJointOrder(SmplFamily family) {
  const std::vector<std::string>& names = SmplFileJointNames(family);
  std::vector<int> order;
  if (family == SmplFamily::kSmpl) {
    for (int j = 0; j < kSmplJoints; ++j) order.push_back(j);
    return order;
  }
  const auto index_of = [&](const std::string& name) {
    return static_cast<int>(std::find(names.begin(), names.end(), name) -
                            names.begin());
  };
  const int left_middle1 = index_of("left_middle1");
  const int right_middle1 = index_of("right_middle1");
  for (int j = 0; j < kBodyJoints; ++j) order.push_back(j);
  order.push_back(left_middle1);
  order.push_back(right_middle1);
  for (int j = kBodyJoints; j < static_cast<int>(names.size()); ++j) {
    if (j != left_middle1 && j != right_middle1) order.push_back(j);
  }
  return order;
}

std::vector<std::string> SmplBodyJointNames(SmplFamily family) {
  const std::vector<std::string>& file_names = SmplFileJointNames(family);
  std::vector<std::string> names;
  for (const int j : SmplJointOrder(family)) names.push_back(file_names[j]);
  for (int j = 0; j < kNumCoreJoints; ++j) names[j] = CoreJointNames()[j];
  return names;
}

BodyModel LoadSmplNpz(const std::filesystem::path& npz,
                      const SmplLoadOptions& options) {
  options.Validate();
  const NpzReader reader(npz);
  const std::string file = npz.string();

  // ---- Read and check shapes.
  const Keyed v_template = ReadKey(reader, "v_template");
  RequireShape(reader, v_template, {-1, 3}, "(V, 3)");
  const int64_t num_vertices = v_template.array.shape[0];
  if (num_vertices < 1) {
    throw IoError(fmt::format("{}: 'v_template' has no vertices", file));
  }
  const Keyed kintree = ReadKey(reader, "kintree_table");
  RequireShape(reader, kintree, {2, -1}, "(2, J)");
  const int64_t num_joints = kintree.array.shape[1];
  SmplFamily family = SmplFamily::kSmpl;
  if (num_joints == kSmplJoints) {
    family = SmplFamily::kSmpl;
  } else if (num_joints == kSmplHJoints) {
    family = SmplFamily::kSmplH;
  } else if (num_joints == kSmplXJoints) {
    family = SmplFamily::kSmplX;
  } else {
    throw IoError(
        fmt::format("{}: 'kintree_table' has {} joints, expected 24 (SMPL), 52 "
                    "(SMPL+H) or 55 (SMPL-X)",
                    file,
                    num_joints));
  }
  const std::string v_text =
      fmt::format("V = {} from 'v_template'", num_vertices);
  const std::string j_text =
      fmt::format("J = {} from 'kintree_table'", num_joints);
  const Keyed faces = ReadKey(reader, "f");
  RequireShape(reader, faces, {-1, 3}, "(F, 3)");
  const Keyed shapedirs = ReadKey(reader, "shapedirs");
  RequireShape(reader,
               shapedirs,
               {num_vertices, 3, -1},
               fmt::format("({}, 3, B) ({})", num_vertices, v_text));
  const Keyed regressor = ReadKey(reader, "J_regressor");
  RequireShape(reader,
               regressor,
               {num_joints, num_vertices},
               fmt::format("({}, {}) ({}, {}; a dense array)",
                           num_joints,
                           num_vertices,
                           j_text,
                           v_text));
  const Keyed weights = ReadKey(reader, "weights");
  RequireShape(
      reader,
      weights,
      {num_vertices, num_joints},
      fmt::format(
          "({}, {}) ({}, {})", num_vertices, num_joints, v_text, j_text));
  const int64_t num_pose_features = 9 * (num_joints - 1);
  Keyed posedirs;
  if (options.load_pose_correctives) {
    posedirs = ReadKey(reader, "posedirs");
    RequireShape(reader,
                 posedirs,
                 {num_vertices, 3, num_pose_features},
                 fmt::format("({}, 3, {}) ({}, 9 (J - 1) with {})",
                             num_vertices,
                             num_pose_features,
                             v_text,
                             j_text));
  }

  const int64_t total_dirs = shapedirs.array.shape[2];
  int64_t max_betas = total_dirs;
  if (family == SmplFamily::kSmplX)
    max_betas = total_dirs > 300 ? 300 : std::min<int64_t>(10, total_dirs);
  if (options.num_betas > max_betas) {
    throw IoError(
        fmt::format("{}: {} betas requested, 'shapedirs' of shape {} holds {} "
                    "shape components{}",
                    file,
                    options.num_betas,
                    shapedirs.array.ShapeString(),
                    max_betas,
                    family == SmplFamily::kSmplX
                        ? " (SMPL-X: the rest are expression components)"
                        : ""));
  }

  // ---- Kinematic tree (file order).
  const std::vector<int64_t> tree = kintree.array.AsInt64();
  std::vector<int> file_parents(num_joints, -2);
  for (int64_t k = 0; k < num_joints; ++k) {
    const int64_t parent = tree[k];
    const int64_t id = tree[num_joints + k];
    if (id < 0 || id >= num_joints || file_parents[id] != -2) {
      throw IoError(fmt::format(
          "{}: 'kintree_table' row 1 must list each joint 0..{} once, got {}",
          file,
          num_joints - 1,
          id));
    }
    const bool root = parent == 4294967295LL || parent == -1;
    if (root != (id == 0)) {
      throw IoError(
          fmt::format("{}: 'kintree_table': joint {} has parent {}; only joint "
                      "0 may be the root "
                      "(parent 4294967295 or -1)",
                      file,
                      id,
                      parent));
    }
    if (!root && (parent < 0 || parent >= num_joints)) {
      throw IoError(fmt::format(
          "{}: 'kintree_table': joint {} has parent {} outside [0, {})",
          file,
          id,
          parent,
          num_joints));
    }
    file_parents[id] = root ? -1 : static_cast<int>(parent);
  }

  // ---- Joint order.
  const std::vector<int> order = SmplJointOrder(family);
  std::vector<int> new_index(num_joints);
  for (int j = 0; j < num_joints; ++j) new_index[order[j]] = j;
  BodyModel body;
  body.name = options.name.empty() ? ToString(family) : options.name;
  body.joint_names = SmplBodyJointNames(family);
  body.parents.resize(num_joints);
  for (int j = 0; j < num_joints; ++j) {
    const int file_parent = file_parents[order[j]];
    body.parents[j] = file_parent < 0 ? -1 : new_index[file_parent];
    if (j > 0 && (body.parents[j] < 0 || body.parents[j] >= j)) {
      throw IoError(fmt::format(
          "{}: 'kintree_table': joint '{}' has parent '{}', which does not "
          "precede it in the "
          "standard {} order",
          file,
          body.joint_names[j],
          body.parents[j] < 0 ? "<root>" : body.joint_names[body.parents[j]],
          ToString(family)));
    }
  }
  if (body.parents[0] != -1) {
    throw IoError(
        fmt::format("{}: 'kintree_table': joint 0 must be the root", file));
  }

  // ---- Mesh in our frame.
  const Eigen::Matrix3d c = SmplToBodyFrame();
  const std::vector<double> verts = FiniteDoubles(reader, v_template);
  body.template_vertices.resize(3, num_vertices);
  for (int64_t v = 0; v < num_vertices; ++v) {
    body.template_vertices.col(v) =
        c * Eigen::Vector3d(verts[3 * v], verts[3 * v + 1], verts[3 * v + 2]);
  }
  const double floor = body.template_vertices.row(2).minCoeff();
  body.template_vertices.row(2).array() -= floor;

  const std::vector<int64_t> face_indices = faces.array.AsInt64();
  body.faces.resize(3, faces.array.shape[0]);
  for (int64_t f = 0; f < faces.array.shape[0]; ++f) {
    for (int k = 0; k < 3; ++k) {
      const int64_t index = face_indices[3 * f + k];
      if (index < 0 || index >= num_vertices) {
        throw IoError(
            fmt::format("{}: 'f' row {} has vertex index {} outside [0, {})",
                        file,
                        f,
                        index,
                        num_vertices));
      }
      body.faces(k, f) = static_cast<int>(index);
    }
  }

  // ---- Shape space.
  const std::vector<double> shape_values = FiniteDoubles(reader, shapedirs);
  const int num_betas = options.num_betas;
  body.shape_dirs.resize(3 * num_vertices, num_betas);
  for (int64_t v = 0; v < num_vertices; ++v) {
    for (int b = 0; b < num_betas; ++b) {
      const Eigen::Vector3d d(shape_values[(3 * v + 0) * total_dirs + b],
                              shape_values[(3 * v + 1) * total_dirs + b],
                              shape_values[(3 * v + 2) * total_dirs + b]);
      body.shape_dirs.block<3, 1>(3 * v, b) = c * d;
    }
  }
  body.beta_stddev = Eigen::VectorXd::Ones(num_betas);

  // ---- Joint regressor (rows permuted).
  const std::vector<double> reg = FiniteDoubles(reader, regressor);
  std::vector<Eigen::Triplet<double>> triplets;
  for (int j = 0; j < num_joints; ++j) {
    const int file_joint = order[j];
    double row_sum = 0.0;
    for (int64_t v = 0; v < num_vertices; ++v) {
      const double w = reg[file_joint * num_vertices + v];
      row_sum += w;
      if (std::abs(w) >= options.sparsity_threshold && w != 0.0) {
        triplets.emplace_back(j, static_cast<int>(v), w);
      }
    }
    if (std::abs(row_sum - 1.0) > kRegressorRowSumTolerance) {
      throw IoError(
          fmt::format("{}: 'J_regressor' row {} ('{}') sums to {}, expected 1 "
                      "(an affine combination of "
                      "vertices)",
                      file,
                      file_joint,
                      SmplFileJointNames(family)[file_joint],
                      row_sum));
    }
  }
  body.joint_regressor.resize(num_joints, num_vertices);
  body.joint_regressor.setFromTriplets(triplets.begin(), triplets.end());
  body.joint_regressor.makeCompressed();

  // ---- Skinning weights (columns permuted, tiny entries dropped, rows
  // renormalised).
  const std::vector<double> w = FiniteDoubles(reader, weights);
  triplets.clear();
  for (int64_t v = 0; v < num_vertices; ++v) {
    double sum = 0.0;
    const size_t start = triplets.size();
    for (int j = 0; j < num_joints; ++j) {
      const double value = w[v * num_joints + order[j]];
      if (value < -1e-6) {
        throw IoError(fmt::format("{}: 'weights' ({}, {}) = {} is negative",
                                  file,
                                  v,
                                  order[j],
                                  value));
      }
      if (value >= options.sparsity_threshold && value > 0.0) {
        triplets.emplace_back(static_cast<int>(v), j, value);
        sum += value;
      }
    }
    if (!(sum > 0.5 && sum < 1.5)) {
      throw IoError(fmt::format(
          "{}: 'weights' row {} sums to {}, expected 1", file, v, sum));
    }
    for (size_t t = start; t < triplets.size(); ++t) {
      triplets[t] = Eigen::Triplet<double>(
          triplets[t].row(), triplets[t].col(), triplets[t].value() / sum);
    }
  }
  body.skinning_weights.resize(num_vertices, num_joints);
  body.skinning_weights.setFromTriplets(triplets.begin(), triplets.end());
  body.skinning_weights.makeCompressed();

  // ---- Pose correctives: posedirs_ours(v, block j) = C posedirs(v, block
  // order[j]) K.
  if (options.load_pose_correctives) {
    const std::vector<double> pose_values = FiniteDoubles(reader, posedirs);
    const Eigen::Matrix<double, 9, 9> k = PoseFeatureMap(c);
    body.pose_dirs.resize(3 * num_vertices, num_pose_features);
    Eigen::Matrix<double, 3, 9> block;
    for (int64_t v = 0; v < num_vertices; ++v) {
      for (int j = 1; j < num_joints; ++j) {
        const int64_t file_block = order[j] - 1;
        for (int a = 0; a < 3; ++a) {
          for (int f = 0; f < 9; ++f) {
            block(a, f) = pose_values[(3 * v + a) * num_pose_features +
                                      9 * file_block + f];
          }
        }
        body.pose_dirs.block<3, 9>(
            3 * v, 9 * static_cast<Eigen::Index>(j - 1)) = c * block * k;
      }
    }
  }

  body.Validate();
  return body;
}

}  // namespace soma
