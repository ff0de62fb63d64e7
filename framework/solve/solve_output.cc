#include "framework/solve/solve_output.h"

#include "framework/core/error.h"
#include "framework/core/file.h"
#include "framework/io/hdf5_util.h"

#include <fmt/format.h>

namespace soma {
namespace {

using hdf5::Check;
using hdf5::CheckStatus;
using hdf5::Hid;

template <typename T>
void WriteArray(hid_t file,
                const char* name,
                const std::vector<hsize_t>& dims,
                const std::vector<T>& values,
                const std::string& source) {
  const std::string what = fmt::format("{}: cannot write '{}'", source, name);
  hsize_t total = 1;
  for (hsize_t d : dims) total *= d;
  SOMA_CHECK_EQ(total, values.size()) << name;
  Hid space = Check(
      H5Screate_simple(static_cast<int>(dims.size()), dims.data(), nullptr),
      H5Sclose,
      what);
  Hid dataset = Check(H5Dcreate2(file,
                                 name,
                                 hdf5::NumberType<T>::File(),
                                 space.get(),
                                 H5P_DEFAULT,
                                 H5P_DEFAULT,
                                 H5P_DEFAULT),
                      H5Dclose,
                      what);
  if (total > 0) {
    CheckStatus(H5Dwrite(dataset.get(),
                         hdf5::NumberType<T>::Memory(),
                         H5S_ALL,
                         H5S_ALL,
                         H5P_DEFAULT,
                         values.data()),
                what);
  }
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
    WriteArray(id, "trans", {f, 3}, trans, source);
    WriteArray(id, "poses", {f, 3 * j}, poses, source);
    WriteArray(id,
               "betas",
               {static_cast<hsize_t>(output.betas.size())},
               std::vector<double>(output.betas.data(),
                                   output.betas.data() + output.betas.size()),
               source);
    WriteArray(
        id, "markers_latent", {m, 3}, flat(output.markers_latent), source);
    WriteArray(
        id, "marker_offsets", {m, 3}, flat(output.marker_offsets), source);
    WriteArray(id, "markers_vids", {m}, vids, source);
    WriteArray(id, "markers_obs", {f, m, 3}, obs, source);
    WriteArray(id, "markers_sim", {f, m, 3}, sim, source);
    WriteArray(id, "termination", {f}, termination, source);
    WriteArray(id, "rms", {f}, rms, source);
    WriteArray(id, "stagei_frames", {stagei.size()}, stagei, source);
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

}  // namespace soma
