#include "framework/solve/pose_prior.h"

#include "framework/config/decode.h"
#include "framework/core/error.h"
#include "framework/core/random.h"
#include "framework/motion/procedural_motion.h"
#include "framework/registry/registry.h"

#include <Eigen/Cholesky>
#include <fmt/format.h>

#include <cmath>
#include <limits>

namespace soma {

GaussianPosePrior::GaussianPosePrior(Eigen::VectorXd mean,
                                     Eigen::MatrixXd sqrt_information)
    : mean_(std::move(mean)), sqrt_information_(std::move(sqrt_information)) {
  if (sqrt_information_.cols() != mean_.size() || mean_.size() == 0) {
    throw ShapeError(
        fmt::format("GaussianPosePrior: mean has {} dofs, sqrt information "
                    "is {} x {}",
                    mean_.size(),
                    sqrt_information_.rows(),
                    sqrt_information_.cols()));
  }
}

GaussianPosePrior GaussianPosePrior::ZeroMean(int num_joints, double stddev) {
  SOMA_CHECK(num_joints >= 2 && stddev > 0) << "ZeroMean prior";
  const int dofs = 3 * (num_joints - 1);
  return GaussianPosePrior(Eigen::VectorXd::Zero(dofs),
                           Eigen::MatrixXd::Identity(dofs, dofs) / stddev);
}

GaussianPosePrior GaussianPosePrior::Fit(const Eigen::MatrixXd& samples,
                                         double shrinkage,
                                         double min_stddev) {
  if (samples.cols() < 2 || samples.rows() == 0) {
    throw ShapeError(fmt::format(
        "GaussianPosePrior::Fit: needs >= 2 samples, got {}", samples.cols()));
  }
  const Eigen::VectorXd mean = samples.rowwise().mean();
  const Eigen::MatrixXd centred = samples.colwise() - mean;
  const Eigen::MatrixXd cov =
      centred * centred.transpose() / static_cast<double>(samples.cols() - 1);
  Eigen::MatrixXd reg = (1.0 - shrinkage) * cov;
  reg.diagonal() += shrinkage * cov.diagonal();
  reg.diagonal().array() += min_stddev * min_stddev;
  const Eigen::MatrixXd information = reg.inverse();
  const Eigen::LLT<Eigen::MatrixXd> llt(information);
  SOMA_CHECK(llt.info() == Eigen::Success) << "pose prior not positive";
  return GaussianPosePrior(mean, llt.matrixL().transpose());
}

void GaussianPosePrior::Evaluate(const double* body_pose,
                                 double* residuals,
                                 double* jacobian) const {
  const int n = num_dofs();
  const Eigen::Map<const Eigen::VectorXd> x(body_pose, n);
  Eigen::Map<Eigen::VectorXd>(residuals, num_residuals()) =
      sqrt_information_ * (x - mean_);
  if (jacobian != nullptr) {
    Eigen::Map<
        Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>>(
        jacobian, num_residuals(), n) = sqrt_information_;
  }
}

Eigen::MatrixXd BodyPoseSamples(const std::vector<PoseSequence>& sequences,
                                int num_joints,
                                int stride) {
  SOMA_CHECK(num_joints >= 2 && stride >= 1) << "BodyPoseSamples";
  int64_t count = 0;
  for (const PoseSequence& seq : sequences) {
    count += (seq.num_frames() + stride - 1) / stride;
  }
  Eigen::MatrixXd samples(3 * (num_joints - 1), count);
  int64_t column = 0;
  for (const PoseSequence& seq : sequences) {
    for (int f = 0; f < seq.num_frames(); f += stride) {
      const Eigen::Matrix3Xd& rotations = seq.frames[f].rotations;
      if (rotations.cols() != num_joints) {
        throw ShapeError(
            fmt::format("BodyPoseSamples: clip '{}' has {} joints, the body {}",
                        seq.name,
                        rotations.cols(),
                        num_joints));
      }
      samples.col(column++) = Eigen::Map<const Eigen::VectorXd>(
          rotations.col(1).data(), 3 * (num_joints - 1));
    }
  }
  return samples;
}

GaussianPosePrior ProceduralPosePrior(
    const BodyModel& body, const ProceduralPosePriorOptions& options) {
  std::vector<std::string> types = options.types;
  if (types.empty()) {
    for (const std::string& type : ProceduralMotionTypes()) {
      if (type != "random_pose") types.push_back(type);
    }
  }
  const Rng rng(options.seed);
  std::vector<PoseSequence> clips;
  ProceduralMotionOptions motion;
  for (const std::string& type : types) {
    for (int c = 0; c < options.clips_per_type; ++c) {
      Rng clip_rng = rng.Stream(fmt::format("pose_prior/{}/{}", type, c));
      clips.push_back(GenerateProceduralMotion(type, body, motion, clip_rng));
    }
  }
  return GaussianPosePrior::Fit(
      BodyPoseSamples(clips, body.num_joints(), options.frame_stride),
      options.shrinkage,
      options.min_stddev);
}

// ---- GmmPosePrior

GmmPosePrior::GmmPosePrior(const GaussianMixture& gmm) {
  gmm.Validate();
  dofs_ = gmm.dim();
  const int k_count = gmm.num_components();
  Eigen::VectorXd c0(k_count);
  for (int k = 0; k < k_count; ++k) {
    const Eigen::MatrixXd information = gmm.covariances[k].inverse();
    const Eigen::LLT<Eigen::MatrixXd> llt(information);
    if (llt.info() != Eigen::Success) {
      throw ShapeError(fmt::format(
          "GmmPosePrior: component {} is not positive definite", k));
    }
    means_.push_back(gmm.means[k]);
    sqrt_information_.push_back(llt.matrixL().transpose());
    // log det Sigma_k = -2 sum log diag(L_k) (L_k the factor of Sigma_k^-1).
    const double log_det =
        -2.0 * llt.matrixL().toDenseMatrix().diagonal().array().log().sum();
    c0[k] = 2.0 * (-std::log(gmm.weights[k]) + 0.5 * log_det);
  }
  offsets_ = c0.array() - c0.minCoeff();
}

int GmmPosePrior::BestComponent(const double* body_pose) const {
  const Eigen::Map<const Eigen::VectorXd> x(body_pose, dofs_);
  int best = 0;
  double best_cost = std::numeric_limits<double>::infinity();
  for (size_t k = 0; k < means_.size(); ++k) {
    const double cost =
        (sqrt_information_[k] * (x - means_[k])).squaredNorm() + offsets_[k];
    if (cost < best_cost) {
      best_cost = cost;
      best = static_cast<int>(k);
    }
  }
  return best;
}

void GmmPosePrior::Evaluate(const double* body_pose,
                            double* residuals,
                            double* jacobian) const {
  const int k = BestComponent(body_pose);
  const Eigen::Map<const Eigen::VectorXd> x(body_pose, dofs_);
  Eigen::Map<Eigen::VectorXd> r(residuals, dofs_ + 1);
  r.head(dofs_) = sqrt_information_[k] * (x - means_[k]);
  r[dofs_] = std::sqrt(offsets_[k]);
  if (jacobian != nullptr) {
    Eigen::Map<
        Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>>
        j(jacobian, dofs_ + 1, dofs_);
    j.topRows(dofs_) = sqrt_information_[k];
    j.row(dofs_).setZero();
  }
}

// ---- Registered sources

namespace {

class ProceduralPriorSource : public PosePriorSource {
 public:
  explicit ProceduralPriorSource(ProceduralPosePriorOptions options)
      : options_(std::move(options)) {}
  std::unique_ptr<PosePrior> Make(const BodyModel& body) const override {
    return std::make_unique<GaussianPosePrior>(
        ProceduralPosePrior(body, options_));
  }

 private:
  ProceduralPosePriorOptions options_;
};

class ZeroMeanPriorSource : public PosePriorSource {
 public:
  explicit ZeroMeanPriorSource(double stddev) : stddev_(stddev) {}
  std::unique_ptr<PosePrior> Make(const BodyModel& body) const override {
    return std::make_unique<GaussianPosePrior>(
        GaussianPosePrior::ZeroMean(body.num_joints(), stddev_));
  }

 private:
  double stddev_;
};

class GmmPriorSource : public PosePriorSource {
 public:
  explicit GmmPriorSource(std::string path) : path_(std::move(path)) {}
  std::unique_ptr<PosePrior> Make(const BodyModel& body) const override {
    const GaussianMixture gmm = ReadGaussianMixture(path_);
    const auto joints = gmm.metadata.find("joint_names");
    if (joints != gmm.metadata.end() && joints->second != body.joint_names) {
      const auto name = gmm.metadata.find("body");
      throw ShapeError(fmt::format(
          "pose_prior.path = {}: fitted for body '{}' with {} joints; the "
          "body being solved, '{}', has {} (fit one with `soma fit_prior "
          "body=...`)",
          path_,
          name == gmm.metadata.end() || name->second.empty()
              ? "?"
              : name->second.front(),
          joints->second.size(),
          body.name,
          body.joint_names.size()));
    }
    if (gmm.dim() != 3 * (body.num_joints() - 1)) {
      throw ShapeError(fmt::format(
          "pose_prior.path = {}: a {}-dimensional mixture, the body needs "
          "3 (J - 1) = {}",
          path_,
          gmm.dim(),
          3 * (body.num_joints() - 1)));
    }
    return std::make_unique<GmmPosePrior>(gmm);
  }

 private:
  std::string path_;
};

class NoPriorSource : public PosePriorSource {
 public:
  std::unique_ptr<PosePrior> Make(const BodyModel&) const override {
    return nullptr;
  }
};

}  // namespace

void RegisterPosePriors() {
  Registry<PosePriorSource>& registry = GetRegistry<PosePriorSource>();
  registry.Register("procedural", [](const ConfigNode& node, BuildContext&) {
    ConfigReader r(node);
    ProceduralPosePriorOptions o;
    r.Read("types", &o.types);
    r.Read("clips_per_type", &o.clips_per_type);
    r.Read("frame_stride", &o.frame_stride);
    r.Read("shrinkage", &o.shrinkage);
    r.Read("min_stddev", &o.min_stddev);
    r.Read("seed", &o.seed);
    r.Finish();
    if (o.clips_per_type < 1 || o.frame_stride < 1 || !(o.shrinkage >= 0) ||
        o.shrinkage > 1 || !(o.min_stddev > 0)) {
      throw ConfigError(fmt::format(
          "Invalid configuration. pose_prior (procedural): clips_per_type = "
          "{}, frame_stride = {}, shrinkage = {}, min_stddev = {}. Violated "
          "constraint: clips_per_type, frame_stride >= 1, 0 <= shrinkage <= "
          "1, min_stddev > 0 (pose_prior.cc)",
          o.clips_per_type,
          o.frame_stride,
          o.shrinkage,
          o.min_stddev));
    }
    return std::make_unique<ProceduralPriorSource>(std::move(o));
  });
  registry.Register("zero_mean", [](const ConfigNode& node, BuildContext&) {
    ConfigReader r(node);
    double stddev = 0.6;
    r.Read("stddev", &stddev);
    r.Finish();
    if (!(stddev > 0)) {
      throw ConfigError(
          fmt::format("Invalid configuration. pose_prior.stddev = {}. Violated "
                      "constraint: stddev > 0 (pose_prior.cc)",
                      stddev));
    }
    return std::make_unique<ZeroMeanPriorSource>(stddev);
  });
  registry.Register("gmm", [](const ConfigNode& node, BuildContext&) {
    ConfigReader r(node);
    std::string path;
    r.Require("path", &path);
    r.Finish();
    return std::make_unique<GmmPriorSource>(std::move(path));
  });
  registry.Register("none", [](const ConfigNode& node, BuildContext&) {
    ConfigReader(node).Finish();
    return std::make_unique<NoPriorSource>();
  });
  RegisterConfigGroup<PosePriorSource>("pose_prior");
}

}  // namespace soma
