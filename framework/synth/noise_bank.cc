#include "framework/synth/noise_bank.h"

#include "framework/core/error.h"
#include "framework/io/hdf5_util.h"  // soma_synth links HDF5::HDF5

#include <fmt/format.h>

#include <algorithm>
#include <array>
#include <mutex>
#include <system_error>
#include <utility>

namespace soma {

void NoiseBank::Validate() const {
  const size_t expected =
      static_cast<size_t>(num_rows) * static_cast<size_t>(num_labels()) * 3;
  if (num_rows < 0 || residuals.size() != expected) {
    throw ShapeError(
        fmt::format("NoiseBank: {} residual values for K = {} rows x L = {} "
                    "labels x 3",
                    residuals.size(),
                    num_rows,
                    num_labels()));
  }
}

NoiseBank BuildNoiseBank(const std::vector<std::string>& labels,
                         const std::vector<float>& observed,
                         const std::vector<float>& simulated,
                         Rng& rng) {
  const size_t num_labels = labels.size();
  if (num_labels == 0) throw ShapeError("BuildNoiseBank: no labels");
  if (observed.size() != simulated.size() ||
      observed.size() % (3 * num_labels) != 0) {
    throw ShapeError(fmt::format(
        "BuildNoiseBank: observed ({} values) and simulated ({} values) "
        "must both be F x L x 3 with L = {}",
        observed.size(),
        simulated.size(),
        num_labels));
  }
  const size_t num_frames = observed.size() / (3 * num_labels);
  auto present = [](const float* p) {
    return p[0] != 0.0f || p[1] != 0.0f || p[2] != 0.0f;
  };
  std::vector<std::vector<std::array<float, 3>>> per_label(num_labels);
  for (size_t f = 0; f < num_frames; ++f) {
    for (size_t l = 0; l < num_labels; ++l) {
      const float* o = observed.data() + 3 * (f * num_labels + l);
      const float* s = simulated.data() + 3 * (f * num_labels + l);
      if (!present(o) || !present(s)) continue;
      per_label[l].push_back({o[0] - s[0], o[1] - s[1], o[2] - s[2]});
    }
  }
  size_t k = 0;
  for (const auto& list : per_label) k = std::max(k, list.size());
  NoiseBank bank;
  bank.labels = labels;
  bank.num_rows = static_cast<int64_t>(k);
  bank.residuals.assign(k * num_labels * 3, 0.0f);
  for (size_t l = 0; l < num_labels; ++l) {
    std::vector<std::array<float, 3>> list = per_label[l];
    if (list.empty()) continue;  // K zero vectors
    const size_t original = list.size();
    while (list.size() < k) {
      list.push_back(list[static_cast<size_t>(
          rng.UniformInt(0, static_cast<int64_t>(original) - 1))]);
    }
    for (size_t i = list.size(); i > 1; --i) {
      std::swap(list[i - 1],
                list[static_cast<size_t>(
                    rng.UniformInt(0, static_cast<int64_t>(i) - 1))]);
    }
    for (size_t row = 0; row < k; ++row) {
      for (int c = 0; c < 3; ++c) {
        bank.residuals[3 * (row * num_labels + l) + c] = list[row][c];
      }
    }
  }
  return bank;
}

namespace {

using hdf5::Check;
using hdf5::CheckStatus;
using hdf5::Hdf5Mutex;
using hdf5::Hid;

constexpr const char* kFormat = "soma-noise-bank";
constexpr int kFormatVersion = 1;

void WriteBankFile(const NoiseBank& bank, const std::string& file) {
  const Hid h5 =
      Check(H5Fcreate(file.c_str(), H5F_ACC_TRUNC, H5P_DEFAULT, H5P_DEFAULT),
            H5Fclose,
            fmt::format("{}: cannot create the noise bank file", file));
  const std::string what = fmt::format("{}: writing the noise bank", file);
  const hsize_t dims[3] = {static_cast<hsize_t>(bank.num_rows),
                           static_cast<hsize_t>(bank.num_labels()),
                           3};
  const Hid space = Check(H5Screate_simple(3, dims, nullptr), H5Sclose, what);
  const Hid props = Check(H5Pcreate(H5P_DATASET_CREATE), H5Pclose, what);
  if (bank.num_rows > 0) {
    const hsize_t chunk[3] = {
        std::min<hsize_t>(dims[0], 1024), dims[1], dims[2]};
    CheckStatus(H5Pset_chunk(props.get(), 3, chunk), what);
    CheckStatus(H5Pset_deflate(props.get(), 4), what);
  }
  const Hid data = Check(H5Dcreate2(h5.get(),
                                    "residuals",
                                    H5T_IEEE_F32LE,
                                    space.get(),
                                    H5P_DEFAULT,
                                    props.get(),
                                    H5P_DEFAULT),
                         H5Dclose,
                         what);
  if (bank.num_rows > 0) {
    CheckStatus(H5Dwrite(data.get(),
                         H5T_NATIVE_FLOAT,
                         H5S_ALL,
                         H5S_ALL,
                         H5P_DEFAULT,
                         bank.residuals.data()),
                what);
  }
  const Hid root = Check(H5Gopen2(h5.get(), "/", H5P_DEFAULT), H5Gclose, what);
  hdf5::WriteStringAttribute(root.get(), "format", kFormat, file);
  hdf5::WriteNumberAttribute<int32_t>(
      root.get(), "format_version", kFormatVersion, file);
  hdf5::WriteNumberAttribute<int32_t>(
      root.get(), "num_labels", bank.num_labels(), file);
  hdf5::WriteStringArrayAttribute(root.get(), "labels", bank.labels, file);
}

}  // namespace

void WriteNoiseBank(const NoiseBank& bank, const std::filesystem::path& path) {
  bank.Validate();
  std::lock_guard lock(Hdf5Mutex());
  const std::filesystem::path tmp = path.string() + ".tmp";
  try {
    WriteBankFile(bank, tmp.string());
  } catch (...) {
    std::error_code ignored;
    std::filesystem::remove(tmp, ignored);
    throw;
  }
  std::error_code error;
  std::filesystem::rename(tmp, path, error);
  if (error) {
    throw IoError(fmt::format("{}: cannot move the noise bank into place: {}",
                              path.string(),
                              error.message()));
  }
}

NoiseBank ReadNoiseBank(const std::filesystem::path& path) {
  std::lock_guard lock(Hdf5Mutex());
  std::string bad;
  const Hid h5 = hdf5::OpenFormattedFile(
      path.string(), "soma noise bank", kFormat, kFormatVersion, &bad);
  NoiseBank bank;
  bank.labels = hdf5::ReadStringArrayAttribute(h5.get(), "labels", bad);
  std::vector<hsize_t> dims;
  bank.residuals = hdf5::ReadDataset<float>(
      h5.get(), "residuals", {0, bank.labels.size(), 3}, bad, &dims);
  bank.num_rows = static_cast<int64_t>(dims[0]);
  return bank;
}

}  // namespace soma
