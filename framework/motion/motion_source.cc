#include "framework/motion/motion_source.h"

#include "framework/config/decode.h"
#include "framework/core/error.h"
#include "framework/io/asf_amc.h"
#include "framework/io/bvh.h"
#include "framework/motion/amass.h"
#include "framework/motion/procedural_motion.h"
#include "framework/motion/retarget.h"
#include "framework/registry/registry.h"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <filesystem>

namespace soma {
namespace {

/// The procedural library: `clips_per_type` clips of every selected type.
class ProceduralMotionSource : public MotionSource {
 public:
  struct Options {
    int clips_per_type = 20;
    std::vector<std::string> types;  // empty: all
    ProceduralMotionOptions motion;
    SplitFractions split;
  };

  explicit ProceduralMotionSource(Options options)
      : options_(std::move(options)) {}

  std::vector<PoseSequence> Load(const BodyModel& body,
                                 Split split,
                                 double frame_rate,
                                 Rng& rng) const override {
    const std::vector<std::string>& types =
        options_.types.empty() ? ProceduralMotionTypes() : options_.types;
    ProceduralMotionOptions motion = options_.motion;
    motion.frame_rate = frame_rate;
    std::vector<PoseSequence> clips;
    for (const std::string& type : types) {
      for (int i = 0; i < options_.clips_per_type; ++i) {
        const std::string name = fmt::format("{}_{:03d}", type, i);
        if (SplitOf(name, rng.seed(), options_.split) != split) continue;
        Rng clip_rng = rng.Stream("motion/procedural/" + name);
        PoseSequence clip =
            GenerateProceduralMotion(type, body, motion, clip_rng);
        clip.name = name;
        clips.push_back(std::move(clip));
      }
    }
    return clips;
  }

 private:
  Options options_;
};

ProceduralMotionSource::Options DecodeProceduralOptions(
    const ConfigNode& node) {
  ConfigReader reader(node);
  ProceduralMotionSource::Options options;
  reader.Read("clips_per_type", &options.clips_per_type);
  reader.Read("types", &options.types);
  reader.Read("duration_s", &options.motion.duration_s);
  reader.Read("joint_jitter_deg", &options.motion.joint_jitter_deg);
  reader.Read("random_pose_range", &options.motion.random_pose_range);
  reader.Read("head_turn_deg", &options.motion.head_turn_deg);
  reader.Read("val_fraction", &options.split.val);
  reader.Read("test_fraction", &options.split.test);
  reader.Check(
      "clips_per_type", options.clips_per_type > 0, "clips_per_type > 0");
  reader.Check("duration_s", options.motion.duration_s > 0, "duration_s > 0");
  reader.Check("random_pose_range",
               options.motion.random_pose_range > 0 &&
                   options.motion.random_pose_range <= 1,
               "0 < random_pose_range <= 1");
  reader.Check(
      "head_turn_deg",
      options.motion.head_turn_deg >= 0 && options.motion.head_turn_deg <= 180,
      "0 <= head_turn_deg <= 180");
  reader.Check("val_fraction",
               options.split.val >= 0 && options.split.test >= 0 &&
                   options.split.val + options.split.test < 1,
               "val_fraction >= 0, test_fraction >= 0, val_fraction + "
               "test_fraction < 1");
  for (const std::string& type : options.types) {
    const auto& known = ProceduralMotionTypes();
    reader.Check(
        "types",
        std::find(known.begin(), known.end(), type) != known.end(),
        fmt::format("every type is one of: {}", fmt::join(known, ", ")));
  }
  reader.Finish();
  return options;
}

/// Files of `dir` with extension `ext`, sorted; IoError if none.
std::vector<std::filesystem::path> ListFiles(const std::string& dir,
                                             const std::string& ext,
                                             const std::string& key) {
  if (!std::filesystem::is_directory(dir)) {
    throw IoError(fmt::format("motion.{}: '{}' is not a directory", key, dir));
  }
  std::vector<std::filesystem::path> files;
  for (const auto& entry : std::filesystem::directory_iterator(dir)) {
    if (entry.is_regular_file() && entry.path().extension() == ext)
      files.push_back(entry.path());
  }
  std::sort(files.begin(), files.end());
  if (files.empty()) {
    throw IoError(
        fmt::format("motion.{}: no *{} files in '{}'", key, ext, dir));
  }
  return files;
}

/// Real clips read from files (BVH or ASF/AMC), retargeted onto the body.
class FileMotionSource : public MotionSource {
 public:
  enum class Format { kBvh, kAsfAmc, kAmass };
  struct Options {
    Format format = Format::kBvh;
    std::string dir;
    double length_to_metres = 0;  // 0: the reader's default
    int max_frames_per_clip = 0;  // 0: all
    SplitFractions split;
  };

  explicit FileMotionSource(Options options) : options_(std::move(options)) {}

  std::vector<PoseSequence> Load(const BodyModel& body,
                                 Split split,
                                 double frame_rate,
                                 Rng& rng) const override {
    std::vector<PoseSequence> clips;
    if (options_.format == Format::kAmass) {
      for (const auto& file : ListFiles(options_.dir, ".npz", "dir")) {
        if (SplitOf(file.stem().string(), rng.seed(), options_.split) != split)
          continue;
        PoseSequence sequence =
            ResamplePoseSequence(LoadAmassNpz(file, body), frame_rate);
        if (options_.max_frames_per_clip > 0 &&
            sequence.num_frames() > options_.max_frames_per_clip) {
          sequence.frames.resize(options_.max_frames_per_clip);
        }
        clips.push_back(std::move(sequence));
      }
    } else if (options_.format == Format::kBvh) {
      for (const auto& file : ListFiles(options_.dir, ".bvh", "dir")) {
        if (SplitOf(file.stem().string(), rng.seed(), options_.split) != split)
          continue;
        BvhReadOptions read;
        if (options_.length_to_metres > 0)
          read.length_to_metres = options_.length_to_metres;
        clips.push_back(Convert(ReadBvh(file, read), body, frame_rate));
      }
    } else {
      const auto skeletons = ListFiles(options_.dir, ".asf", "dir");
      for (const auto& file : ListFiles(options_.dir, ".amc", "dir")) {
        if (SplitOf(file.stem().string(), rng.seed(), options_.split) != split)
          continue;
        // The skeleton whose stem is the longest prefix of the clip's stem
        // (HDM_bd.asf for HDM_bd_squat1Reps_003_120.amc).
        const std::filesystem::path* asf = nullptr;
        for (const auto& candidate : skeletons) {
          const std::string stem = candidate.stem().string();
          if (file.stem().string().rfind(stem + "_", 0) == 0 &&
              (asf == nullptr || stem.size() > asf->stem().string().size())) {
            asf = &candidate;
          }
        }
        if (asf == nullptr) {
          throw IoError(
              fmt::format("{}: no .asf skeleton in '{}' whose name prefixes it",
                          file.string(),
                          options_.dir));
        }
        AsfAmcReadOptions read;
        if (options_.length_to_metres > 0)
          read.length_to_metres = options_.length_to_metres;
        clips.push_back(
            Convert(ReadAsfAmc(*asf, file, read), body, frame_rate));
      }
    }
    return clips;
  }

 private:
  PoseSequence Convert(MotionClip clip,
                       const BodyModel& body,
                       double frame_rate) const {
    clip = ConvertYUpToZUp(ResampleClip(clip, frame_rate));
    PoseSequence sequence = Retarget(
        clip, body, DetectRetargetMap(clip.skeleton, clip.source_path));
    if (options_.max_frames_per_clip > 0 &&
        sequence.num_frames() > options_.max_frames_per_clip) {
      sequence.frames.resize(options_.max_frames_per_clip);
    }
    return sequence;
  }

  Options options_;
};

FileMotionSource::Options DecodeFileOptions(const ConfigNode& node,
                                            FileMotionSource::Format format) {
  ConfigReader reader(node);
  FileMotionSource::Options options;
  options.format = format;
  reader.Require("dir", &options.dir);
  reader.Read("length_to_metres", &options.length_to_metres);
  reader.Read("max_frames_per_clip", &options.max_frames_per_clip);
  reader.Read("val_fraction", &options.split.val);
  reader.Read("test_fraction", &options.split.test);
  reader.Check("length_to_metres",
               options.length_to_metres >= 0,
               "length_to_metres >= 0 (0 = the format's default)");
  reader.Check("max_frames_per_clip",
               options.max_frames_per_clip >= 0,
               "max_frames_per_clip >= 0");
  reader.Check("val_fraction",
               options.split.val >= 0 && options.split.test >= 0 &&
                   options.split.val + options.split.test <= 1,
               "val_fraction >= 0, test_fraction >= 0, val_fraction + "
               "test_fraction <= 1");
  reader.Finish();
  return options;
}

}  // namespace

std::string_view ToString(Split split) {
  switch (split) {
    case Split::kTrain:
      return "train";
    case Split::kVal:
      return "val";
    case Split::kTest:
      return "test";
  }
  return "train";
}

Split SplitFromString(std::string_view text) {
  if (text == "train") return Split::kTrain;
  if (text == "val") return Split::kVal;
  if (text == "test") return Split::kTest;
  throw ConfigError(
      fmt::format("Unknown split '{}'; expected train, val or test", text));
}

Split SplitOf(std::string_view clip_name,
              uint64_t seed,
              const SplitFractions& fractions) {
  const uint64_t h = Mix64(Fnv1a64(clip_name) ^ Mix64(seed));
  const double u = static_cast<double>(h >> 11) * 0x1.0p-53;
  if (u < fractions.val) return Split::kVal;
  if (u < fractions.val + fractions.test) return Split::kTest;
  return Split::kTrain;
}

void RegisterMotionSources() {
  Registry<MotionSource>& registry = GetRegistry<MotionSource>();
  registry.Register("procedural", [](const ConfigNode& node, BuildContext&) {
    return std::make_unique<ProceduralMotionSource>(
        DecodeProceduralOptions(node));
  });
  registry.Register("bvh", [](const ConfigNode& node, BuildContext&) {
    return std::make_unique<FileMotionSource>(
        DecodeFileOptions(node, FileMotionSource::Format::kBvh));
  });
  registry.Register("asf_amc", [](const ConfigNode& node, BuildContext&) {
    return std::make_unique<FileMotionSource>(
        DecodeFileOptions(node, FileMotionSource::Format::kAsfAmc));
  });
  registry.Register("amass", [](const ConfigNode& node, BuildContext&) {
    return std::make_unique<FileMotionSource>(
        DecodeFileOptions(node, FileMotionSource::Format::kAmass));
  });
  RegisterConfigGroup<MotionSource>("motion");
}

}  // namespace soma
