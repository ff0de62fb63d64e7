#include "framework/solve/gaussian_mixture.h"

#include "framework/core/error.h"
#include "framework/core/file.h"
#include "framework/core/random.h"
#include "framework/io/hdf5_util.h"

#include <Eigen/Cholesky>
#include <fmt/format.h>

#include <cmath>
#include <limits>
#include <numbers>

namespace soma {
namespace {

constexpr const char* kFormat = "soma-gmm";
constexpr int kFormatVersion = 1;

/// Per-component Cholesky factors and log-normalisers of a mixture.
struct Factorised {
  std::vector<Eigen::LLT<Eigen::MatrixXd>> llt;
  Eigen::VectorXd log_norm;  // log w_k - 1/2 log det Sigma_k - D/2 log 2 pi
};

Factorised Factorise(const GaussianMixture& gmm) {
  Factorised f;
  const int k_count = gmm.num_components();
  const double d = gmm.dim();
  f.log_norm.resize(k_count);
  for (int k = 0; k < k_count; ++k) {
    f.llt.emplace_back(gmm.covariances[k]);
    if (f.llt.back().info() != Eigen::Success) {
      throw ShapeError(fmt::format(
          "GaussianMixture: covariance {} is not positive definite", k));
    }
    const double half_log_det =
        f.llt.back().matrixLLT().diagonal().array().log().sum();
    f.log_norm[k] = std::log(gmm.weights[k]) - half_log_det -
                    0.5 * d * std::log(2.0 * std::numbers::pi);
  }
  return f;
}

/// N x K log(w_k N(x_n; mu_k, Sigma_k)).
Eigen::MatrixXd WeightedLogDensities(const GaussianMixture& gmm,
                                     const Factorised& f,
                                     const Eigen::MatrixXd& x) {
  Eigen::MatrixXd log_p(x.cols(), gmm.num_components());
  for (int k = 0; k < gmm.num_components(); ++k) {
    Eigen::MatrixXd centred = x.colwise() - gmm.means[k];
    f.llt[k].matrixL().solveInPlace(centred);
    log_p.col(k) =
        (f.log_norm[k] - 0.5 * centred.colwise().squaredNorm().array())
            .transpose();
  }
  return log_p;
}

/// Row-wise log-sum-exp of `log_p` (N x K).
Eigen::VectorXd LogSumExpRows(const Eigen::MatrixXd& log_p) {
  const Eigen::VectorXd row_max = log_p.rowwise().maxCoeff();
  return row_max.array() +
         (log_p.colwise() - row_max).array().exp().rowwise().sum().log();
}

Eigen::MatrixXd Covariance(const Eigen::MatrixXd& x,
                           const Eigen::VectorXd& mean) {
  const Eigen::MatrixXd centred = x.colwise() - mean;
  return centred * centred.transpose() /
         std::max<double>(1.0, static_cast<double>(x.cols()) - 1.0);
}

/// k-means++ seeding followed by a few Lloyd iterations: the initial
/// hard partition of the samples into K clusters.
std::vector<int> KMeansPartition(const Eigen::MatrixXd& x,
                                 int k_count,
                                 Rng& rng) {
  const int n = static_cast<int>(x.cols());
  Eigen::MatrixXd centres(x.rows(), k_count);
  centres.col(0) = x.col(rng.UniformInt(0, n - 1));
  Eigen::VectorXd nearest =
      (x.colwise() - centres.col(0)).colwise().squaredNorm().transpose();
  for (int k = 1; k < k_count; ++k) {
    const double total = nearest.sum();
    int pick = static_cast<int>(rng.UniformInt(0, n - 1));
    if (total > 0) {
      double u = rng.Uniform() * total;
      for (int i = 0; i < n; ++i) {
        u -= nearest[i];
        if (u <= 0) {
          pick = i;
          break;
        }
      }
    }
    centres.col(k) = x.col(pick);
    nearest = nearest.cwiseMin(
        (x.colwise() - centres.col(k)).colwise().squaredNorm().transpose());
  }
  std::vector<int> label(n, 0);
  for (int iteration = 0; iteration < 10; ++iteration) {
    for (int i = 0; i < n; ++i) {
      (centres.colwise() - x.col(i))
          .colwise()
          .squaredNorm()
          .minCoeff(&label[i]);
    }
    Eigen::MatrixXd sums = Eigen::MatrixXd::Zero(x.rows(), k_count);
    Eigen::VectorXd counts = Eigen::VectorXd::Zero(k_count);
    for (int i = 0; i < n; ++i) {
      sums.col(label[i]) += x.col(i);
      counts[label[i]] += 1.0;
    }
    for (int k = 0; k < k_count; ++k) {
      if (counts[k] > 0) centres.col(k) = sums.col(k) / counts[k];
    }
  }
  return label;
}

}  // namespace

void GaussianMixture::Validate() const {
  const int k_count = num_components();
  const int d = dim();
  if (k_count == 0 || d == 0 || static_cast<int>(means.size()) != k_count ||
      static_cast<int>(covariances.size()) != k_count) {
    throw ShapeError(fmt::format(
        "GaussianMixture: {} weights, {} means, {} covariances (expected the "
        "same number K >= 1, dimension >= 1)",
        k_count,
        means.size(),
        covariances.size()));
  }
  if (!(weights.array() > 0).all() || std::abs(weights.sum() - 1.0) > 1e-6) {
    throw ShapeError("GaussianMixture: weights must be positive and sum to 1");
  }
  for (int k = 0; k < k_count; ++k) {
    if (means[k].size() != d || covariances[k].rows() != d ||
        covariances[k].cols() != d) {
      throw ShapeError(fmt::format(
          "GaussianMixture: component {} has a mean of size {} and a {} x {} "
          "covariance, expected {} and {} x {}",
          k,
          means[k].size(),
          covariances[k].rows(),
          covariances[k].cols(),
          d,
          d,
          d));
    }
    if (!means[k].allFinite() || !covariances[k].allFinite() ||
        (covariances[k] - covariances[k].transpose()).cwiseAbs().maxCoeff() >
            1e-9 * (1.0 + covariances[k].cwiseAbs().maxCoeff())) {
      throw ShapeError(fmt::format(
          "GaussianMixture: component {} is not finite or its covariance is "
          "not symmetric",
          k));
    }
  }
  Factorise(*this);  // throws if a covariance is not positive definite
}

Eigen::VectorXd GaussianMixture::LogDensity(
    const Eigen::MatrixXd& samples) const {
  if (samples.rows() != dim()) {
    throw ShapeError(fmt::format(
        "GaussianMixture::LogDensity: samples have {} rows, the mixture {} "
        "dimensions",
        samples.rows(),
        dim()));
  }
  const Factorised f = Factorise(*this);
  return LogSumExpRows(WeightedLogDensities(*this, f, samples));
}

void GmmFitOptions::Validate() const {
  const auto bad = [](std::string_view key,
                      const std::string& value,
                      std::string_view constraint) {
    return ConfigError(
        fmt::format("Invalid configuration. {} = {}. Violated constraint: {} "
                    "(gaussian_mixture.cc)",
                    key,
                    value,
                    constraint));
  };
  if (components < 1) {
    throw bad("components", std::to_string(components), "components >= 1");
  }
  if (max_iterations < 1) {
    throw bad("max_iterations", std::to_string(max_iterations), ">= 1");
  }
  if (!(tolerance >= 0)) {
    throw bad("tolerance", std::to_string(tolerance), "tolerance >= 0");
  }
  if (!(min_stddev > 0)) {
    throw bad("min_stddev", std::to_string(min_stddev), "min_stddev > 0");
  }
}

GaussianMixture FitGaussianMixture(const Eigen::MatrixXd& samples,
                                   const GmmFitOptions& options,
                                   GmmFitReport* report) {
  options.Validate();
  const int n = static_cast<int>(samples.cols());
  const int d = static_cast<int>(samples.rows());
  const int k_count = options.components;
  if (d == 0 || n < std::max(2, k_count)) {
    throw ShapeError(fmt::format(
        "FitGaussianMixture: {} samples of dimension {} for {} components "
        "(need at least max(2, components) samples)",
        n,
        d,
        k_count));
  }
  if (!samples.allFinite()) {
    throw ShapeError("FitGaussianMixture: samples contain NaN or inf");
  }
  const double floor = options.min_stddev * options.min_stddev;
  const Eigen::MatrixXd global_cov =
      Covariance(samples, samples.rowwise().mean()) +
      floor * Eigen::MatrixXd::Identity(d, d);

  // Initial mixture from a k-means partition.
  Rng rng = Rng(options.seed).Stream("gmm/kmeans++");
  const std::vector<int> label = KMeansPartition(samples, k_count, rng);
  GaussianMixture gmm;
  gmm.weights.resize(k_count);
  for (int k = 0; k < k_count; ++k) {
    std::vector<int> members;
    for (int i = 0; i < n; ++i) {
      if (label[i] == k) members.push_back(i);
    }
    if (members.size() < 2) {
      gmm.means.push_back(samples.col(rng.UniformInt(0, n - 1)));
      gmm.covariances.push_back(global_cov);
      gmm.weights[k] = 1.0 / n;
      continue;
    }
    Eigen::MatrixXd x(d, members.size());
    for (size_t i = 0; i < members.size(); ++i)
      x.col(i) = samples.col(members[i]);
    gmm.means.push_back(x.rowwise().mean());
    gmm.covariances.push_back(Covariance(x, gmm.means.back()) +
                              floor * Eigen::MatrixXd::Identity(d, d));
    gmm.weights[k] = static_cast<double>(members.size()) / n;
  }
  gmm.weights /= gmm.weights.sum();

  // Expectation-maximisation.
  GmmFitReport fit;
  double previous = -std::numeric_limits<double>::infinity();
  for (int iteration = 1; iteration <= options.max_iterations; ++iteration) {
    const Factorised f = Factorise(gmm);
    const Eigen::MatrixXd log_p = WeightedLogDensities(gmm, f, samples);
    const Eigen::VectorXd log_lik = LogSumExpRows(log_p);
    fit.mean_log_likelihood = log_lik.mean();
    fit.iterations = iteration;
    if (fit.mean_log_likelihood - previous < options.tolerance) {
      fit.converged = true;
      break;
    }
    previous = fit.mean_log_likelihood;
    const Eigen::MatrixXd resp = (log_p.colwise() - log_lik).array().exp();
    for (int k = 0; k < k_count; ++k) {
      const double nk = resp.col(k).sum();
      if (nk < 2.0) {
        // A collapsed component restarts at the worst-explained sample.
        int worst = 0;
        log_lik.minCoeff(&worst);
        gmm.means[k] = samples.col(worst);
        gmm.covariances[k] = global_cov;
        gmm.weights[k] = 1.0 / n;
        continue;
      }
      gmm.weights[k] = nk / n;
      gmm.means[k] = samples * resp.col(k) / nk;
      const Eigen::MatrixXd centred = samples.colwise() - gmm.means[k];
      gmm.covariances[k] =
          centred * resp.col(k).asDiagonal() * centred.transpose() / nk;
      gmm.covariances[k] =
          0.5 * (gmm.covariances[k] + gmm.covariances[k].transpose());
      gmm.covariances[k].diagonal().array() += floor;
    }
    gmm.weights /= gmm.weights.sum();
  }
  if (report != nullptr) *report = fit;
  return gmm;
}

void WriteGaussianMixture(const std::filesystem::path& path,
                          const GaussianMixture& gmm) {
  gmm.Validate();
  const std::string source = path.string();
  const hsize_t k_count = gmm.num_components();
  const hsize_t d = gmm.dim();
  std::vector<double> weights(gmm.weights.data(), gmm.weights.data() + k_count);
  std::vector<double> means;
  std::vector<double> covariances;
  for (hsize_t k = 0; k < k_count; ++k) {
    means.insert(means.end(), gmm.means[k].data(), gmm.means[k].data() + d);
    // Row-major D x D (symmetric, so the storage order does not matter).
    covariances.insert(covariances.end(),
                       gmm.covariances[k].data(),
                       gmm.covariances[k].data() + d * d);
  }
  std::vector<std::string> keys;
  for (const auto& [key, values] : gmm.metadata) keys.push_back(key);

  CreateDirectories(path.parent_path().empty() ? "." : path.parent_path());
  const std::filesystem::path temp = TempPathFor(path);
  {
    std::lock_guard lock(hdf5::Hdf5Mutex());
    hdf5::Hid file = hdf5::Check(
        H5Fcreate(temp.c_str(), H5F_ACC_TRUNC, H5P_DEFAULT, H5P_DEFAULT),
        H5Fclose,
        fmt::format("{}: cannot create the file", source));
    const hid_t id = file.get();
    hdf5::WriteDataset(id, "weights", {k_count}, weights, source);
    hdf5::WriteDataset(id, "means", {k_count, d}, means, source);
    hdf5::WriteDataset(id, "covariances", {k_count, d, d}, covariances, source);
    hdf5::WriteStringAttribute(id, "format", kFormat, source);
    hdf5::WriteNumberAttribute<int32_t>(
        id, "format_version", kFormatVersion, source);
    hdf5::WriteStringArrayAttribute(id, "metadata_keys", keys, source);
    for (const auto& [key, values] : gmm.metadata) {
      hdf5::WriteStringArrayAttribute(
          id, ("meta_" + key).c_str(), values, source);
    }
    if (!file.Reset()) {
      throw IoError(fmt::format("{}: closing the file failed", source));
    }
  }
  CommitTempFile(temp, path);
}

GaussianMixture ReadGaussianMixture(const std::filesystem::path& path) {
  std::lock_guard lock(hdf5::Hdf5Mutex());
  std::string bad;
  const hdf5::Hid file = hdf5::OpenFormattedFile(
      path.string(), "soma GMM", kFormat, kFormatVersion, &bad);
  const hid_t id = file.get();
  std::vector<hsize_t> dims;
  const std::vector<double> weights =
      hdf5::ReadDataset<double>(id, "weights", {0}, bad, &dims);
  const hsize_t k_count = dims[0];
  const std::vector<double> means =
      hdf5::ReadDataset<double>(id, "means", {k_count, 0}, bad, &dims);
  const hsize_t d = dims[1];
  const std::vector<double> covariances =
      hdf5::ReadDataset<double>(id, "covariances", {k_count, d, d}, bad);

  GaussianMixture gmm;
  gmm.weights = Eigen::Map<const Eigen::VectorXd>(weights.data(), k_count);
  for (hsize_t k = 0; k < k_count; ++k) {
    gmm.means.push_back(
        Eigen::Map<const Eigen::VectorXd>(means.data() + k * d, d));
    gmm.covariances.push_back(Eigen::Map<const Eigen::MatrixXd>(
        covariances.data() + k * d * d, d, d));
  }
  for (const std::string& key :
       hdf5::ReadStringArrayAttribute(id, "metadata_keys", bad)) {
    gmm.metadata[key] =
        hdf5::ReadStringArrayAttribute(id, ("meta_" + key).c_str(), bad);
  }
  try {
    gmm.Validate();
  } catch (const ShapeError& e) {
    throw IoError(bad + e.what());
  }
  return gmm;
}

}  // namespace soma
