// `soma inspect`: the body, its markers and a pose, exported for a person to
// look at — OBJ and PLY meshes with the markers, a CSV of marker positions
// and a PNG with front and side views, markers drawn and labelled.
#include "framework/body/mesh_export.h"
#include "framework/body/render.h"
#include "framework/config/decode.h"
#include "framework/core/error.h"
#include "framework/core/file.h"
#include "framework/core/logging.h"
#include "framework/motion/anatomy.h"
#include "framework/tasks/components.h"
#include "framework/tasks/task.h"

#include <fmt/format.h>

#include <sstream>

namespace soma {
namespace {

struct InspectOptions {
  std::string pose = "standing";  // rest | standing | motion
  int clip = 0;                   // pose=motion: clip index in the train split
  int frame = 0;                  // pose=motion: frame of that clip
  std::vector<double> betas;      // shape coefficients (missing = 0)
  int render_size = 600;          // pixels per view
  bool labels = true;             // draw marker labels
};

InspectOptions DecodeInspectOptions(const ConfigNode& node) {
  ConfigReader reader(node);
  InspectOptions options;
  reader.Read("pose", &options.pose);
  reader.Read("clip", &options.clip);
  reader.Read("frame", &options.frame);
  reader.Read("betas", &options.betas);
  reader.Read("render_size", &options.render_size);
  reader.Read("labels", &options.labels);
  reader.Check("pose",
               options.pose == "rest" || options.pose == "standing" ||
                   options.pose == "motion",
               "pose is rest, standing or motion");
  reader.Check("clip", options.clip >= 0, "clip >= 0");
  reader.Check("frame", options.frame >= 0, "frame >= 0");
  reader.Check("render_size",
               options.render_size >= 64 && options.render_size <= 4096,
               "64 <= render_size <= 4096");
  reader.Finish();
  return options;
}

class InspectTask : public Task {
 public:
  explicit InspectTask(InspectOptions options) : options_(std::move(options)) {}

  void Run(const ConfigNode& cfg, RunContext& ctx) override {
    BuildContext build(ctx.seed, ctx.output_dir.string());
    const BodyModel body = BuildBody(cfg, build);
    const MarkerLayout layout = BuildLayout(cfg, body, build);
    if (static_cast<int>(options_.betas.size()) > body.num_betas()) {
      throw ConfigError(
          fmt::format("Invalid configuration. task.betas has {} values but "
                      "body '{}' has {} shape "
                      "components",
                      options_.betas.size(),
                      body.name,
                      body.num_betas()));
    }
    Eigen::VectorXd betas = Eigen::VectorXd::Zero(body.num_betas());
    for (size_t i = 0; i < options_.betas.size(); ++i)
      betas[i] = options_.betas[i];

    BodyPose pose = BodyPose::Rest(body.num_joints());
    std::string pose_name = options_.pose;
    if (options_.pose == "standing") {
      pose = ToBodyPose(StandingPose(),
                        Eigen::Vector3d::Zero(),
                        Eigen::Vector3d::Zero(),
                        body.num_joints());
    } else if (options_.pose == "motion") {
      Rng rng = Rng(ctx.seed).Stream("task/inspect");
      const std::vector<PoseSequence> clips =
          BuildMotionSource(cfg, build)->Load(body, Split::kTrain, 30.0, rng);
      if (options_.clip >= static_cast<int>(clips.size())) {
        throw ConfigError(
            fmt::format("Invalid configuration. task.clip = {}. Violated "
                        "constraint: clip < {} (clips in "
                        "the train split of the motion source)",
                        options_.clip,
                        clips.size()));
      }
      const PoseSequence& clip = clips[options_.clip];
      if (options_.frame >= clip.num_frames()) {
        throw ConfigError(
            fmt::format("Invalid configuration. task.frame = {}. Violated "
                        "constraint: frame < {} (frames "
                        "of clip '{}')",
                        options_.frame,
                        clip.num_frames(),
                        clip.name));
      }
      pose = clip.frames[options_.frame];
      pose_name = fmt::format("{} frame {}", clip.name, options_.frame);
    }

    const Eigen::Matrix3Xd vertices = PoseVertices(body, betas, pose);
    const Eigen::Matrix3Xd normals = VertexNormals(vertices, body.faces);
    const Eigen::Matrix3Xd markers = MarkerPositions(layout, vertices, normals);
    const std::vector<std::string> labels = layout.Labels();

    ColoredPoints points;
    points.positions = markers;
    points.colors.assign(markers.cols(), CategoricalColor(3));
    WriteObj(
        ctx.output_dir / "body.obj", vertices, body.faces, normals, points);
    WritePly(ctx.output_dir / "body_markers.ply", vertices, body.faces, points);
    std::ostringstream csv;
    csv << "label,vertex_id,x,y,z\n";
    for (int m = 0; m < markers.cols(); ++m) {
      csv << fmt::format("{},{},{:.6f},{:.6f},{:.6f}\n",
                         labels[m],
                         layout.markers[m].vertex_ids.front(),
                         markers(0, m),
                         markers(1, m),
                         markers(2, m));
    }
    WriteFileAtomic(ctx.output_dir / "markers.csv", csv.str());
    RenderOptions render;
    render.view_size = options_.render_size;
    render.labels = options_.labels;
    render.title = fmt::format(
        "{} body, {} markers, {}", body.name, layout.num_markers(), pose_name);
    RenderBodyViews(vertices, body.faces, markers, labels, render)
        .WritePng(ctx.output_dir / "render.png");
    const double stature =
        vertices.row(2).maxCoeff() - vertices.row(2).minCoeff();
    SOMA_LOG(INFO,
             "inspect: wrote body.obj, body_markers.ply, markers.csv, "
             "render.png to {}",
             ctx.output_dir.string());
    ctx.ReportMetric("height_m", stature);
    ctx.ReportMetric("num_markers", layout.num_markers());
  }

 private:
  InspectOptions options_;
};

}  // namespace

void RegisterInspectTask(Registry<Task>& registry) {
  registry.Register("inspect", [](const ConfigNode& node, BuildContext&) {
    return std::make_unique<InspectTask>(DecodeInspectOptions(node));
  });
}

}  // namespace soma
