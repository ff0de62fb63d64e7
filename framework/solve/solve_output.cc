#include "framework/solve/solve_output.h"

#include "framework/core/error.h"
#include "framework/core/file.h"
#include "framework/io/hdf5_util.h"

#include <fmt/format.h>

#include <cmath>
#include <system_error>

namespace soma {
namespace {

using hdf5::Check;
using hdf5::Hid;

constexpr char kFormat[] = "soma-solve";

/// Columns of a row-major N x 3 array as a 3 x N matrix.
Eigen::Matrix3Xd ToMatrix3X(const double* data, hsize_t n) {
  return Eigen::Map<const Eigen::Matrix3Xd>(
      data, 3, static_cast<Eigen::Index>(n));
}

}  // namespace

void WriteSolveOutput(const std::filesystem::path& path,
                      const SolveOutput& output) {
  const std::string source = path.string();
  const hsize_t f = output.frame_params.size();
  const hsize_t m = output.labels.size();
  const hsize_t j = output.joint_names.size();
  if (output.observed.size() != f || output.simulated.size() != f ||
      output.summaries.size() != f) {
    throw ShapeError(fmt::format("{}: inconsistent per-frame arrays", source));
  }
  std::vector<double> trans, poses, rms;
  std::vector<float> obs, sim;
  std::vector<int32_t> termination;
  for (hsize_t t = 0; t < f; ++t) {
    const Eigen::VectorXd& p = output.frame_params[t];
    if (static_cast<hsize_t>(p.size()) != 3 + 3 * j ||
        static_cast<hsize_t>(output.observed[t].cols()) != m ||
        static_cast<hsize_t>(output.simulated[t].cols()) != m) {
      throw ShapeError(
          fmt::format("{}: frame {} has the wrong size", source, t));
    }
    trans.insert(trans.end(), p.data(), p.data() + 3);
    poses.insert(poses.end(), p.data() + 3, p.data() + p.size());
    for (hsize_t k = 0; k < 3 * m; ++k) {
      obs.push_back(static_cast<float>(output.observed[t].data()[k]));
      sim.push_back(static_cast<float>(output.simulated[t].data()[k]));
    }
    termination.push_back(
        static_cast<int32_t>(output.summaries[t].termination));
    rms.push_back(output.summaries[t].usable() ? output.summaries[t].rms_m
                                               : std::nan(""));
  }
  const auto flat = [](const Eigen::Matrix3Xd& x) {
    return std::vector<double>(x.data(), x.data() + x.size());
  };
  std::vector<int32_t> vids(output.marker_vertex_ids.begin(),
                            output.marker_vertex_ids.end());
  std::vector<int32_t> stagei(output.stagei_frames.begin(),
                              output.stagei_frames.end());

  CreateDirectories(path.parent_path().empty() ? "." : path.parent_path());
  const std::filesystem::path temp = TempPathFor(path);
  {
    std::lock_guard lock(hdf5::Hdf5Mutex());
    Hid file =
        Check(H5Fcreate(temp.c_str(), H5F_ACC_TRUNC, H5P_DEFAULT, H5P_DEFAULT),
              H5Fclose,
              fmt::format("{}: cannot create the file", source));
    const hid_t id = file.get();
    hdf5::WriteDataset(id, "trans", {f, 3}, trans, source);
    hdf5::WriteDataset(id, "poses", {f, 3 * j}, poses, source);
    hdf5::WriteDataset(
        id,
        "betas",
        {static_cast<hsize_t>(output.betas.size())},
        std::vector<double>(output.betas.data(),
                            output.betas.data() + output.betas.size()),
        source);
    hdf5::WriteDataset(
        id, "markers_latent", {m, 3}, flat(output.markers_latent), source);
    hdf5::WriteDataset(
        id, "marker_offsets", {m, 3}, flat(output.marker_offsets), source);
    hdf5::WriteDataset(id, "markers_vids", {m}, vids, source);
    hdf5::WriteDataset(id, "markers_obs", {f, m, 3}, obs, source);
    hdf5::WriteDataset(id, "markers_sim", {f, m, 3}, sim, source);
    hdf5::WriteDataset(id, "termination", {f}, termination, source);
    hdf5::WriteDataset(id, "rms", {f}, rms, source);
    hdf5::WriteDataset(id, "stagei_frames", {stagei.size()}, stagei, source);
    hdf5::WriteStringAttribute(id, "format", "soma-solve", source);
    hdf5::WriteStringAttribute(id, "body", output.body, source);
    hdf5::WriteStringArrayAttribute(id, "labels", output.labels, source);
    hdf5::WriteStringArrayAttribute(
        id, "joint_names", output.joint_names, source);
    hdf5::WriteNumberAttribute<double>(
        id, "frame_rate", output.frame_rate, source);
    hdf5::WriteNumberAttribute<int64_t>(
        id, "num_frames", static_cast<int64_t>(f), source);
    if (!file.Reset()) {
      throw IoError(fmt::format("{}: closing the file failed", source));
    }
  }
  CommitTempFile(temp, path);
}

SolveOutput ReadSolveOutput(const std::filesystem::path& path) {
  const std::string source = path.string();
  std::lock_guard lock(hdf5::Hdf5Mutex());
  std::string bad;
  const Hid file = hdf5::OpenFormattedFile(
      source, "soma solve output", kFormat, /*version=*/0, &bad);
  const hid_t id = file.get();
  SolveOutput out;
  out.body = hdf5::ReadStringAttribute(id, "body", bad);
  out.labels = hdf5::ReadStringArrayAttribute(id, "labels", bad);
  out.joint_names = hdf5::ReadStringArrayAttribute(id, "joint_names", bad);
  out.frame_rate = hdf5::ReadNumberAttribute<double>(id, "frame_rate", bad);
  const int64_t num_frames =
      hdf5::ReadNumberAttribute<int64_t>(id, "num_frames", bad);

  const hsize_t f = static_cast<hsize_t>(std::max<int64_t>(num_frames, 0));
  const hsize_t m = out.labels.size();
  const hsize_t j = out.joint_names.size();
  const auto read_double = [&](const char* name,
                               const std::vector<hsize_t>& dims) {
    return hdf5::ReadDataset<double>(id, name, dims, bad);
  };
  const auto read_int = [&](const char* name,
                            const std::vector<hsize_t>& dims) {
    return hdf5::ReadDataset<int32_t>(id, name, dims, bad);
  };
  const auto read_float = [&](const char* name,
                              const std::vector<hsize_t>& dims) {
    return hdf5::ReadDataset<float>(id, name, dims, bad);
  };
  // Shapes: F = num_frames, J = joint names, M = labels (0: any size).
  const std::vector<double> trans = read_double("trans", {f, 3});
  const std::vector<double> poses = read_double("poses", {f, 3 * j});
  const std::vector<double> betas = read_double("betas", {0});
  const std::vector<double> latent = read_double("markers_latent", {m, 3});
  const std::vector<double> offsets = read_double("marker_offsets", {m, 3});
  const std::vector<int32_t> vids = read_int("markers_vids", {m});
  const std::vector<float> obs = read_float("markers_obs", {f, m, 3});
  const std::vector<float> sim = read_float("markers_sim", {f, m, 3});
  const std::vector<int32_t> termination = read_int("termination", {f});
  const std::vector<double> rms = read_double("rms", {f});
  const std::vector<int32_t> stagei = read_int("stagei_frames", {0});

  out.betas = Eigen::Map<const Eigen::VectorXd>(
      betas.data(), static_cast<Eigen::Index>(betas.size()));
  out.markers_latent = ToMatrix3X(latent.data(), m);
  out.marker_offsets = ToMatrix3X(offsets.data(), m);
  out.marker_vertex_ids.assign(vids.begin(), vids.end());
  out.stagei_frames.assign(stagei.begin(), stagei.end());
  out.frame_params.resize(f);
  out.observed.resize(f);
  out.simulated.resize(f);
  out.summaries.resize(f);
  for (hsize_t t = 0; t < f; ++t) {
    Eigen::VectorXd& p = out.frame_params[t];
    p.resize(static_cast<Eigen::Index>(3 + 3 * j));
    for (hsize_t k = 0; k < 3; ++k) p(k) = trans[3 * t + k];
    for (hsize_t k = 0; k < 3 * j; ++k) {
      p(static_cast<Eigen::Index>(3 + k)) = poses[3 * j * t + k];
    }
    out.observed[t].resize(3, static_cast<Eigen::Index>(m));
    out.simulated[t].resize(3, static_cast<Eigen::Index>(m));
    for (hsize_t k = 0; k < 3 * m; ++k) {
      out.observed[t].data()[k] = obs[3 * m * t + k];
      out.simulated[t].data()[k] = sim[3 * m * t + k];
    }
    const int32_t code = termination[t];
    if (code < static_cast<int32_t>(SolveTermination::kConverged) ||
        code > static_cast<int32_t>(SolveTermination::kSkipped)) {
      throw IoError(fmt::format(
          "{}dataset 'termination' has {} at frame {}, expected 0..3",
          bad,
          code,
          t));
    }
    SolveSummary& summary = out.summaries[t];
    summary.frame = static_cast<int>(t);
    summary.termination = static_cast<SolveTermination>(code);
    summary.rms_m = rms[t];
  }
  return out;
}

}  // namespace soma
