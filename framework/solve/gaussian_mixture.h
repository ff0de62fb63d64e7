// A Gaussian mixture over R^D: the density behind the GMM pose prior
// (MoSh++'s pose prior is an 8-component mixture over body joint
// rotations). Fitted by expectation-maximisation with k-means++ seeding and
// stored as HDF5:
//   /weights      K float64, summing to 1
//   /means        K x D float64
//   /covariances  K x D x D float64 (symmetric positive definite)
// attributes: format "soma-gmm", format_version 1, plus the free-form
// string attributes of GaussianMixture::metadata (e.g. body, joint_names,
// sources for a pose prior). Written atomically.
#pragma once

#include <Eigen/Core>

#include <cstdint>
#include <filesystem>
#include <map>
#include <string>
#include <vector>

namespace soma {

struct GaussianMixture {
  Eigen::VectorXd weights;                   // K
  std::vector<Eigen::VectorXd> means;        // K of D
  std::vector<Eigen::MatrixXd> covariances;  // K of D x D
  /// Free-form attributes stored with the mixture (string -> string list).
  std::map<std::string, std::vector<std::string>> metadata;

  int num_components() const { return static_cast<int>(weights.size()); }
  int dim() const {
    return means.empty() ? 0 : static_cast<int>(means[0].size());
  }

  /// ShapeError unless sizes agree, weights are positive and sum to 1
  /// (within 1e-6) and every covariance is symmetric positive definite.
  void Validate() const;

  /// log p(x) = log sum_k w_k N(x; mu_k, Sigma_k) for each column of
  /// `samples` (D x N).
  Eigen::VectorXd LogDensity(const Eigen::MatrixXd& samples) const;
};

struct GmmFitOptions {
  int components = 8;
  int max_iterations = 300;
  /// EM stops when the mean log-likelihood improves by less than this.
  double tolerance = 1e-5;
  /// Added to every covariance's diagonal after each M step (variance
  /// floor, like scikit-learn's reg_covar): min_stddev^2.
  double min_stddev = 0.02;
  uint64_t seed = 0;      // k-means++ seeding
  void Validate() const;  // ConfigError naming the option
};

struct GmmFitReport {
  int iterations = 0;
  bool converged = false;
  double mean_log_likelihood = 0.0;  // per sample, on the fitted samples
};

/// Fits a mixture to the columns of `samples` (D x N, N >= components).
/// Deterministic for a given seed. Throws ShapeError on too few samples.
GaussianMixture FitGaussianMixture(const Eigen::MatrixXd& samples,
                                   const GmmFitOptions& options,
                                   GmmFitReport* report = nullptr);

void WriteGaussianMixture(const std::filesystem::path& path,
                          const GaussianMixture& gmm);
/// IoError naming the file and what is wrong (missing dataset, wrong
/// format/version, inconsistent shapes); the mixture is validated.
GaussianMixture ReadGaussianMixture(const std::filesystem::path& path);

}  // namespace soma
