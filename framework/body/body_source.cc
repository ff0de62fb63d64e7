#include "framework/body/body_source.h"

#include "framework/body/makehuman_body.h"
#include "framework/body/procedural_body.h"
#include "framework/body/smpl_body.h"
#include "framework/config/decode.h"
#include "framework/core/error.h"
#include "framework/registry/registry.h"

#include <fmt/format.h>

namespace soma {
namespace {

class ProceduralBodySource : public BodySource {
 public:
  explicit ProceduralBodySource(ProceduralBodyOptions options)
      : options_(options) {}
  BodyModel Build() const override { return MakeProceduralBody(options_); }

 private:
  ProceduralBodyOptions options_;
};

ProceduralBodyOptions DecodeProceduralBodyOptions(const ConfigNode& node) {
  ConfigReader reader(node);
  ProceduralBodyOptions options;
  reader.Read("grid_spacing", &options.grid_spacing);
  reader.Read("target_vertices", &options.target_vertices);
  reader.Read("num_betas", &options.num_betas);
  reader.Read("relax_iterations", &options.relax_iterations);
  reader.Read("blend_radius", &options.blend_radius);
  reader.Finish();
  options.Validate();
  return options;
}

class MakeHumanBodySource : public BodySource {
 public:
  MakeHumanBodySource(std::string dir, MakeHumanLoadOptions options)
      : dir_(std::move(dir)), options_(options) {}
  BodyModel Build() const override { return LoadMakeHumanBody(dir_, options_); }

 private:
  std::string dir_;
  MakeHumanLoadOptions options_;
};

std::unique_ptr<BodySource> MakeMakeHumanSource(const ConfigNode& node) {
  ConfigReader reader(node);
  std::string dir;
  std::string rest_pose = "t_pose";
  std::string proportions = "anthropometric";
  MakeHumanLoadOptions options;
  reader.Require("dir", &dir);
  reader.Read("rest_pose", &rest_pose);
  reader.Read("proportions", &proportions);
  reader.Read("upper_arm_ratio", &options.upper_arm_ratio);
  reader.Read("num_betas", &options.num_betas);
  reader.Read("metres_per_unit", &options.metres_per_unit);
  reader.Read("regressor_support_factor", &options.regressor_support_factor);
  reader.Check("rest_pose",
               rest_pose == "t_pose" || rest_pose == "asset",
               "rest_pose is t_pose or asset");
  reader.Check("proportions",
               proportions == "anthropometric" || proportions == "asset",
               "proportions is anthropometric or asset");
  reader.Finish();
  options.proportions = proportions == "anthropometric"
                            ? MakeHumanLoadOptions::Proportions::kAnthropometric
                            : MakeHumanLoadOptions::Proportions::kAsset;
  options.rest_pose = rest_pose == "t_pose"
                          ? MakeHumanLoadOptions::RestPose::kTPose
                          : MakeHumanLoadOptions::RestPose::kAsset;
  options.Validate();
  return std::make_unique<MakeHumanBodySource>(dir, options);
}

class SmplBodySource : public BodySource {
 public:
  SmplBodySource(std::string path, SmplLoadOptions options)
      : path_(std::move(path)), options_(std::move(options)) {}
  BodyModel Build() const override { return LoadSmplNpz(path_, options_); }

 private:
  std::string path_;
  SmplLoadOptions options_;
};

std::unique_ptr<BodySource> MakeSmplSource(const ConfigNode& node) {
  ConfigReader reader(node);
  std::string path;
  SmplLoadOptions options;
  reader.Require("path", &path);
  reader.Read("num_betas", &options.num_betas);
  reader.Read("load_pose_correctives", &options.load_pose_correctives);
  reader.Finish();
  options.Validate();
  return std::make_unique<SmplBodySource>(path, options);
}

constexpr std::string_view kExcludeKey = "layout.exclude";

/// The canonical labels of `labels` that `exclude` keeps, in order.
std::vector<std::string> KeptCanonicalLabels(
    const std::vector<std::string>& labels,
    const std::vector<std::string>& exclude) {
  std::vector<std::string> kept;
  for (int i : KeptLabelPositions(labels, exclude, kExcludeKey)) {
    kept.push_back(CanonicalMarkerLabel(labels[i]));
  }
  return kept;
}

class BuiltinLayoutSource : public LayoutSource {
 public:
  BuiltinLayoutSource(std::string layout, std::vector<std::string> exclude)
      : layout_(std::move(layout)), exclude_(std::move(exclude)) {}
  MarkerLayout Build(const BodyModel& body) const override {
    return ExcludeMarkers(
        MakeBuiltinLayout(body, layout_), exclude_, kExcludeKey);
  }
  std::vector<std::string> Labels() const override {
    return KeptCanonicalLabels(BuiltinLayoutLabels(layout_), exclude_);
  }

 private:
  std::string layout_;
  std::vector<std::string> exclude_;
};

class FileLayoutSource : public LayoutSource {
 public:
  FileLayoutSource(std::string path,
                   std::vector<std::string> exclude,
                   LayoutCheckOptions check)
      : path_(std::move(path)), exclude_(std::move(exclude)), check_(check) {}
  MarkerLayout Build(const BodyModel& body) const override {
    return ExcludeMarkers(
        LoadMarkerLayoutForBody(path_, body, check_), exclude_, kExcludeKey);
  }
  std::vector<std::string> Labels() const override {
    MarkerLayout file = CanonicalizeLayout(ReadMarkerLayout(path_));
    file.Sort();
    return KeptCanonicalLabels(file.Labels(), exclude_);
  }

 private:
  std::string path_;
  std::vector<std::string> exclude_;
  LayoutCheckOptions check_;
};

}  // namespace

void RegisterBodySources() {
  Registry<BodySource>& bodies = GetRegistry<BodySource>();
  bodies.Register("procedural", [](const ConfigNode& node, BuildContext&) {
    return std::make_unique<ProceduralBodySource>(
        DecodeProceduralBodyOptions(node));
  });
  bodies.Register("makehuman", [](const ConfigNode& node, BuildContext&) {
    return MakeMakeHumanSource(node);
  });
  bodies.Register("smplx", [](const ConfigNode& node, BuildContext&) {
    return MakeSmplSource(node);
  });
  RegisterConfigGroup<BodySource>("body");

  Registry<LayoutSource>& layouts = GetRegistry<LayoutSource>();
  layouts.Register("builtin", [](const ConfigNode& node, BuildContext&) {
    ConfigReader reader(node);
    std::string layout;
    reader.Require("layout", &layout);
    const auto& names = BuiltinLayoutNames();
    reader.Check("layout",
                 std::find(names.begin(), names.end(), layout) != names.end(),
                 fmt::format("one of {}", fmt::join(names, ", ")));
    std::vector<std::string> exclude;
    reader.Read("exclude", &exclude);
    reader.Finish();
    auto source = std::make_unique<BuiltinLayoutSource>(layout, exclude);
    (void)source->Labels();  // an unknown excluded label fails here
    return source;
  });
  layouts.Register("file", [](const ConfigNode& node, BuildContext&) {
    ConfigReader reader(node);
    std::string path;
    reader.Require("path", &path);
    std::vector<std::string> exclude;
    reader.Read("exclude", &exclude);
    LayoutCheckOptions check;
    reader.Read("allow_unknown_labels", &check.allow_unknown_labels);
    reader.Finish();
    return std::make_unique<FileLayoutSource>(path, exclude, check);
  });
  RegisterConfigGroup<LayoutSource>("layout");
}

}  // namespace soma
