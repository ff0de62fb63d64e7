#include "framework/io/asf_amc.h"

#include "framework/core/error.h"
#include "framework/core/file.h"
#include "framework/io/line_error.h"

#include <fmt/format.h>

#include <cctype>
#include <charconv>
#include <cmath>
#include <limits>
#include <map>
#include <vector>

namespace soma {
namespace {

constexpr double kInchToMetres = 0.0254;
constexpr double kDegToRad = M_PI / 180.0;
constexpr double kDefaultFrameRate = 120.0;

std::string ToLower(std::string_view text) {
  std::string out(text);
  for (char& c : out)
    c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
  return out;
}

// A line split into words: comments ('#' to the end of the line) removed;
// commas and parentheses are whitespace (Acclaim definition).
struct Line {
  int number = 0;  // 1-based
  std::vector<std::string_view> words;
};

std::vector<Line> SplitIntoLines(std::string_view text) {
  std::vector<Line> lines;
  int number = 0;
  size_t start = 0;
  while (start < text.size()) {
    size_t end = text.find('\n', start);
    if (end == std::string_view::npos) end = text.size();
    std::string_view line = text.substr(start, end - start);
    start = end + 1;
    ++number;
    const size_t hash = line.find('#');
    if (hash != std::string_view::npos) line = line.substr(0, hash);
    Line out{number, {}};
    size_t i = 0;
    auto is_space = [](char c) {
      return c == ' ' || c == '\t' || c == '\r' || c == '\f' || c == '\v' ||
             c == ',' || c == '(' || c == ')';
    };
    while (i < line.size()) {
      while (i < line.size() && is_space(line[i])) ++i;
      const size_t word_start = i;
      while (i < line.size() && !is_space(line[i])) ++i;
      if (i > word_start)
        out.words.push_back(line.substr(word_start, i - word_start));
    }
    if (!out.words.empty()) lines.push_back(std::move(out));
  }
  return lines;
}

std::optional<double> ParseNumber(std::string_view text, bool allow_infinite) {
  if (!text.empty() && text.front() == '+') text.remove_prefix(1);
  double value = 0.0;
  const auto [end, error] =
      std::from_chars(text.data(), text.data() + text.size(), value);
  if (error != std::errc() || end != text.data() + text.size() ||
      std::isnan(value) || (!allow_infinite && std::isinf(value))) {
    return std::nullopt;
  }
  return value;
}

// Rotation about fixed axes applied in `order` (e.g. "XYZ": X first, so
// R = Rz * Ry * Rx); angles[k] is the angle about axis k (x, y, z), radians.
Eigen::Quaterniond FixedAxesRotation(std::string_view order,
                                     const Eigen::Vector3d& angles) {
  Eigen::Quaterniond rotation = Eigen::Quaterniond::Identity();
  for (char c : order) {
    const int axis = std::toupper(static_cast<unsigned char>(c)) - 'X';
    rotation = Eigen::Quaterniond(Eigen::AngleAxisd(
                   angles[axis], Eigen::Vector3d::Unit(axis))) *
               rotation;
  }
  return rotation.normalized();
}

bool IsAxisOrder(std::string_view order) {
  if (order.size() != 3) return false;
  std::string upper = ToLower(order);
  for (char& c : upper)
    c = static_cast<char>(std::toupper(static_cast<unsigned char>(c)));
  return upper.find('X') != std::string::npos &&
         upper.find('Y') != std::string::npos &&
         upper.find('Z') != std::string::npos;
}

std::optional<ChannelType> ParseDof(std::string_view token) {
  const std::string lower = ToLower(token);
  if (lower == "rx") return ChannelType::kXRotation;
  if (lower == "ry") return ChannelType::kYRotation;
  if (lower == "rz") return ChannelType::kZRotation;
  if (lower == "tx") return ChannelType::kXPosition;
  if (lower == "ty") return ChannelType::kYPosition;
  if (lower == "tz") return ChannelType::kZPosition;
  return std::nullopt;
}

// One `:bonedata` entry, file units.
struct RawBone {
  int line = 0;  // the `begin` line
  std::string name;
  std::optional<Eigen::Vector3d> direction;
  std::optional<double> length;
  std::optional<Eigen::Vector3d> axis;  // angles in the ASF angle unit
  std::string axis_order = "XYZ";
  std::vector<ChannelType> dofs;
  int dof_line = 0;
  std::vector<std::pair<double, double>> limits;  // ASF angle unit
};

class AsfParser {
 public:
  AsfParser(std::string_view text,
            const std::filesystem::path& source,
            const AsfAmcReadOptions& options)
      : source_(source), options_(options), lines_(SplitIntoLines(text)) {}

  AsfSkeleton Parse() {
    size_t i = 0;
    bool saw_bonedata = false;
    bool saw_hierarchy = false;
    while (i < lines_.size()) {
      const Line& line = lines_[i];
      const std::string_view keyword = line.words[0];
      if (keyword.front() != ':') {
        ThrowAtLine(source_,
                    line.number,
                    "expected a ':section' keyword, got '{}'",
                    keyword);
      }
      ++i;
      if (keyword == ":version") {
        continue;
      } else if (keyword == ":name") {
        for (size_t k = 1; k < line.words.size(); ++k) {
          if (k > 1) name_ += ' ';
          name_ += line.words[k];
        }
      } else if (keyword == ":units") {
        ParseUnits(&i);
      } else if (keyword == ":root") {
        ParseRoot(&i);
      } else if (keyword == ":bonedata") {
        ParseBoneData(&i);
        saw_bonedata = true;
      } else if (keyword == ":hierarchy") {
        ParseHierarchy(&i, line.number);
        saw_hierarchy = true;
      } else {
        // :documentation and sections this reader does not use (:skin, ...)
        // run to the next ':' keyword.
        SkipSection(&i);
      }
    }
    const int last_line = lines_.empty() ? 1 : lines_.back().number;
    if (!saw_bonedata)
      ThrowAtLine(source_, last_line, "missing :bonedata section");
    if (!saw_hierarchy)
      ThrowAtLine(source_, last_line, "missing :hierarchy section");
    return Build();
  }

 private:
  bool AtSection(size_t i) const {
    return i >= lines_.size() || lines_[i].words[0].front() == ':';
  }

  void SkipSection(size_t* i) const {
    while (!AtSection(*i)) ++*i;
  }

  double Number(const Line& line,
                size_t k,
                std::string_view what,
                bool allow_infinite = false) const {
    if (k >= line.words.size()) {
      ThrowAtLine(
          source_, line.number, "missing {} after '{}'", what, line.words[0]);
    }
    const std::optional<double> value =
        ParseNumber(line.words[k], allow_infinite);
    if (!value)
      ThrowAtLine(source_,
                  line.number,
                  "{} is not a number: '{}'",
                  what,
                  line.words[k]);
    return *value;
  }

  Eigen::Vector3d Vector(const Line& line, std::string_view what) const {
    if (line.words.size() != 4) {
      ThrowAtLine(source_,
                  line.number,
                  "'{}' needs 3 numbers, got {}",
                  line.words[0],
                  line.words.size() - 1);
    }
    return {
        Number(line, 1, what), Number(line, 2, what), Number(line, 3, what)};
  }

  double AngleToRadians(double value) const {
    return degrees_ ? value * kDegToRad : value;
  }

  void ParseUnits(size_t* i) {
    for (; !AtSection(*i); ++*i) {
      const Line& line = lines_[*i];
      if (line.words.size() != 2) {
        ThrowAtLine(
            source_, line.number, "expected '<unit> <value>' in :units");
      }
      const std::string key = ToLower(line.words[0]);
      if (key == "length") {
        length_unit_ = Number(line, 1, "the length unit");
        if (length_unit_ <= 0.0)
          ThrowAtLine(source_, line.number, "length unit must be > 0");
      } else if (key == "angle") {
        const std::string unit = ToLower(line.words[1]);
        if (unit != "deg" && unit != "rad") {
          ThrowAtLine(source_,
                      line.number,
                      "angle unit '{}' is not deg or rad",
                      line.words[1]);
        }
        degrees_ = unit == "deg";
      } else if (key == "mass") {
        Number(line, 1, "the mass unit");
      } else {
        ThrowAtLine(source_,
                    line.number,
                    "unknown unit '{}' (expected mass, length, angle)",
                    line.words[0]);
      }
    }
  }

  void ParseRoot(size_t* i) {
    for (; !AtSection(*i); ++*i) {
      const Line& line = lines_[*i];
      const std::string key = ToLower(line.words[0]);
      if (key == "order") {
        root_order_.clear();
        for (size_t k = 1; k < line.words.size(); ++k) {
          const std::optional<ChannelType> dof = ParseDof(line.words[k]);
          if (!dof)
            ThrowAtLine(source_,
                        line.number,
                        "unknown root channel '{}'",
                        line.words[k]);
          root_order_.push_back(*dof);
        }
      } else if (key == "axis") {
        if (line.words.size() != 2 || !IsAxisOrder(line.words[1])) {
          ThrowAtLine(
              source_, line.number, "expected 'axis <order>' such as XYZ");
        }
        root_axis_order_ = std::string(line.words[1]);
      } else if (key == "position") {
        root_position_ = Vector(line, "a root position");
      } else if (key == "orientation") {
        root_orientation_ = Vector(line, "a root orientation");
      } else {
        ThrowAtLine(
            source_, line.number, "unknown :root keyword '{}'", line.words[0]);
      }
    }
  }

  void ParseBoneData(size_t* i) {
    while (!AtSection(*i)) {
      const Line& begin = lines_[*i];
      if (begin.words[0] != "begin" || begin.words.size() != 1) {
        ThrowAtLine(source_,
                    begin.number,
                    "expected 'begin' in :bonedata, got '{}'",
                    begin.words[0]);
      }
      RawBone bone;
      bone.line = begin.number;
      ++*i;
      bool ended = false;
      while (!AtSection(*i)) {
        const Line& line = lines_[*i];
        ++*i;
        const std::string key = ToLower(line.words[0]);
        if (key == "end") {
          ended = true;
          break;
        }
        ParseBoneLine(line, key, &bone, i);
      }
      if (!ended)
        ThrowAtLine(source_, begin.number, "bone block without 'end'");
      if (bone.name.empty())
        ThrowAtLine(source_, begin.number, "bone without a name");
      if (!bone.direction)
        ThrowAtLine(
            source_, begin.number, "bone '{}' has no direction", bone.name);
      if (!bone.length)
        ThrowAtLine(
            source_, begin.number, "bone '{}' has no length", bone.name);
      if (!bone.axis)
        ThrowAtLine(source_, begin.number, "bone '{}' has no axis", bone.name);
      if (!bone.limits.empty() && bone.limits.size() != bone.dofs.size()) {
        ThrowAtLine(source_,
                    bone.dof_line,
                    "bone '{}' has {} dofs but {} limits",
                    bone.name,
                    bone.dofs.size(),
                    bone.limits.size());
      }
      const std::string key = ToLower(bone.name);
      if (key == "root" || bone_index_.count(key) > 0) {
        ThrowAtLine(
            source_, begin.number, "duplicate bone name '{}'", bone.name);
      }
      bone_index_[key] = static_cast<int>(bones_.size());
      bones_.push_back(std::move(bone));
    }
  }

  void ParseBoneLine(const Line& line,
                     const std::string& key,
                     RawBone* bone,
                     size_t* i) {
    if (key == "id") {
      Number(line, 1, "the bone id");
    } else if (key == "name") {
      if (line.words.size() != 2)
        ThrowAtLine(source_, line.number, "expected 'name <bone>'");
      bone->name = std::string(line.words[1]);
    } else if (key == "direction") {
      Eigen::Vector3d direction = Vector(line, "a direction component");
      bone->direction = direction;
    } else if (key == "length") {
      if (line.words.size() != 2)
        ThrowAtLine(source_, line.number, "expected 'length <value>'");
      bone->length = Number(line, 1, "the length");
      if (*bone->length < 0.0)
        ThrowAtLine(source_, line.number, "negative bone length");
    } else if (key == "axis") {
      if (line.words.size() != 5 || !IsAxisOrder(line.words[4])) {
        ThrowAtLine(source_,
                    line.number,
                    "expected 'axis <ax> <ay> <az> <order>' such as XYZ");
      }
      bone->axis = Eigen::Vector3d(Number(line, 1, "an axis angle"),
                                   Number(line, 2, "an axis angle"),
                                   Number(line, 3, "an axis angle"));
      bone->axis_order = std::string(line.words[4]);
    } else if (key == "dof") {
      bone->dof_line = line.number;
      for (size_t k = 1; k < line.words.size(); ++k) {
        const std::optional<ChannelType> dof = ParseDof(line.words[k]);
        if (!dof) {
          ThrowAtLine(
              source_,
              line.number,
              "unknown dof '{}' (expected rx ry rz; tx ty tz l on bones are "
              "not supported)",
              line.words[k]);
        }
        if (!IsRotation(*dof)) {
          ThrowAtLine(source_,
                      line.number,
                      "translational dof '{}' on bone '{}' is not supported",
                      line.words[k],
                      bone->name);
        }
        bone->dofs.push_back(*dof);
      }
      if (bone->dofs.empty() || bone->dofs.size() > 3) {
        ThrowAtLine(source_,
                    line.number,
                    "expected 1 to 3 dofs, got {}",
                    bone->dofs.size());
      }
    } else if (key == "limits") {
      if (bone->dofs.empty())
        ThrowAtLine(source_, line.number, "limits before dof");
      // (lo hi) pairs, one per dof, usually one per line.
      std::vector<double> values;
      const Line* current = &line;
      size_t k = 1;
      while (values.size() < 2 * bone->dofs.size()) {
        if (k >= current->words.size()) {
          const bool more = *i < lines_.size() && !AtSection(*i) &&
                            ParseNumber(lines_[*i].words[0], true).has_value();
          if (!more) {
            ThrowAtLine(
                source_,
                current->number,
                "bone '{}' needs {} limit pairs (one per dof), got {} numbers",
                bone->name,
                bone->dofs.size(),
                values.size());
          }
          current = &lines_[(*i)++];
          k = 0;
          continue;
        }
        values.push_back(
            Number(*current, k++, "a limit", /*allow_infinite=*/true));
      }
      if (k < current->words.size()) {
        ThrowAtLine(source_,
                    current->number,
                    "extra value '{}' after the limits",
                    current->words[k]);
      }
      for (size_t d = 0; d < bone->dofs.size(); ++d) {
        bone->limits.emplace_back(values[2 * d], values[2 * d + 1]);
      }
    } else if (key == "bodymass" || key == "cofmass") {
      Number(line, 1, key);
    } else {
      ThrowAtLine(source_,
                  line.number,
                  "unknown :bonedata keyword '{}'",
                  line.words[0]);
    }
  }

  void ParseHierarchy(size_t* i, int section_line) {
    if (AtSection(*i) || lines_[*i].words[0] != "begin") {
      ThrowAtLine(source_, section_line, ":hierarchy must start with 'begin'");
    }
    ++*i;
    while (true) {
      if (AtSection(*i))
        ThrowAtLine(source_, section_line, ":hierarchy without 'end'");
      const Line& line = lines_[(*i)++];
      if (line.words[0] == "end") break;
      if (line.words.size() < 2) {
        ThrowAtLine(source_,
                    line.number,
                    "expected '<parent> <child> ...' in :hierarchy");
      }
      const int parent = BoneId(line, line.words[0]);
      for (size_t k = 1; k < line.words.size(); ++k) {
        const int child = BoneId(line, line.words[k]);
        if (child == kRoot)
          ThrowAtLine(source_, line.number, "the root cannot be a child");
        if (parent_of_.count(child) > 0) {
          ThrowAtLine(source_,
                      line.number,
                      "bone '{}' has a second parent",
                      line.words[k]);
        }
        parent_of_[child] = parent;
        children_[parent].push_back(child);
      }
    }
  }

  int BoneId(const Line& line, std::string_view name) const {
    const std::string key = ToLower(name);
    if (key == "root") return kRoot;
    const auto it = bone_index_.find(key);
    if (it == bone_index_.end()) {
      ThrowAtLine(
          source_, line.number, "unknown bone '{}' in :hierarchy", name);
    }
    return it->second;
  }

  AsfSkeleton Build() {
    AsfSkeleton asf;
    asf.name = name_;
    asf.source_path = source_.string();
    asf.angles_in_degrees = degrees_;
    const double scale =
        options_.length_to_metres.value_or(kInchToMetres / length_unit_);
    asf.length_to_metres = scale;
    asf.root_position = root_position_ * scale;

    Skeleton& skeleton = asf.skeleton;
    skeleton.euler_convention = EulerConvention::kFixedAxes;
    const Eigen::Vector3d orientation = root_orientation_.unaryExpr(
        [&](double a) { return AngleToRadians(a); });
    AddJoint(&skeleton,
             "root",
             -1,
             Eigen::Vector3d::Zero(),
             FixedAxesRotation(root_axis_order_, orientation),
             {});
    for (ChannelType type : root_order_) skeleton.channels[0].push_back({type});
    AddChildren(&skeleton, kRoot, 0, scale);

    for (size_t b = 0; b < bones_.size(); ++b) {
      if (skeleton.Find(bones_[b].name) < 0) {
        ThrowAtLine(source_,
                    bones_[b].line,
                    "bone '{}' is not connected to the root in :hierarchy",
                    bones_[b].name);
      }
    }
    skeleton.Validate();
    return asf;
  }

  static void AddJoint(Skeleton* skeleton,
                       std::string name,
                       int parent,
                       const Eigen::Vector3d& offset,
                       const Eigen::Quaterniond& dof_frame,
                       std::vector<Channel> channels) {
    skeleton->names.push_back(std::move(name));
    skeleton->parents.push_back(parent);
    skeleton->offsets.push_back(offset);
    skeleton->dof_frames.push_back(dof_frame);
    skeleton->channels.push_back(std::move(channels));
  }

  Eigen::Vector3d BoneVector(const RawBone& bone, double scale) const {
    const double norm = bone.direction->norm();
    if (norm == 0.0) {
      if (*bone.length != 0.0) {
        ThrowAtLine(
            source_, bone.line, "bone '{}' has a zero direction", bone.name);
      }
      return Eigen::Vector3d::Zero();
    }
    return *bone.direction / norm * (*bone.length * scale);
  }

  // Appends the bones below `bone` (kRoot or a bone index) in pre-order;
  // `joint` is the joint of `bone`, placed at the bone's start.
  void AddChildren(
      Skeleton* skeleton, int bone, int joint, double scale, int depth = 0) {
    // Real skeletons are < 50 deep; this bounds the recursion on bad input.
    constexpr int kMaxDepth = 1000;
    if (depth > kMaxDepth) {
      ThrowAtLine(
          source_, bones_[bone].line, "bone chain deeper than {}", kMaxDepth);
    }
    const Eigen::Vector3d tip = bone == kRoot ? Eigen::Vector3d::Zero()
                                              : BoneVector(bones_[bone], scale);
    const auto it = children_.find(bone);
    if (it == children_.end() || it->second.empty()) {
      if (bone != kRoot) {
        const auto clash =
            bone_index_.find(ToLower(bones_[bone].name + "_end"));
        if (clash != bone_index_.end()) {
          ThrowAtLine(source_,
                      bones_[clash->second].line,
                      "bone '{}_end' clashes with the tip joint of bone '{}'",
                      bones_[bone].name,
                      bones_[bone].name);
        }
        AddJoint(skeleton,
                 bones_[bone].name + "_end",
                 joint,
                 tip,
                 Eigen::Quaterniond::Identity(),
                 {});
      }
      return;
    }
    for (int child : it->second) {
      const RawBone& raw = bones_[child];
      const Eigen::Vector3d axis =
          raw.axis->unaryExpr([&](double a) { return AngleToRadians(a); });
      std::vector<Channel> channels;
      for (size_t d = 0; d < raw.dofs.size(); ++d) {
        Channel channel{raw.dofs[d]};
        if (!raw.limits.empty()) {
          channel.lower = AngleToRadians(raw.limits[d].first);
          channel.upper = AngleToRadians(raw.limits[d].second);
        }
        channels.push_back(channel);
      }
      const int child_joint = skeleton->num_joints();
      AddJoint(skeleton,
               raw.name,
               joint,
               tip,
               FixedAxesRotation(raw.axis_order, axis),
               std::move(channels));
      AddChildren(skeleton, child, child_joint, scale, depth + 1);
    }
  }

  static constexpr int kRoot = -1;

  std::filesystem::path source_;
  AsfAmcReadOptions options_;
  std::vector<Line> lines_;
  std::string name_;
  double length_unit_ = 1.0;
  bool degrees_ = true;
  std::vector<ChannelType> root_order_ = {ChannelType::kXPosition,
                                          ChannelType::kYPosition,
                                          ChannelType::kZPosition,
                                          ChannelType::kXRotation,
                                          ChannelType::kYRotation,
                                          ChannelType::kZRotation};
  std::string root_axis_order_ = "XYZ";
  Eigen::Vector3d root_position_ = Eigen::Vector3d::Zero();
  Eigen::Vector3d root_orientation_ = Eigen::Vector3d::Zero();
  std::vector<RawBone> bones_;
  std::map<std::string, int> bone_index_;  // lower-case name -> bones_ index
  std::map<int, int> parent_of_;
  std::map<int, std::vector<int>> children_;
};

double InferFrameRate(const std::filesystem::path& source) {
  const std::string stem = source.stem().string();
  if (stem.rfind("HDM_", 0) == 0) {
    const size_t underscore = stem.rfind('_');
    const std::string_view whole = stem;
    const std::string_view suffix = whole.substr(underscore + 1);
    int rate = 0;
    const auto [end, error] =
        std::from_chars(suffix.data(), suffix.data() + suffix.size(), rate);
    if (error == std::errc() && end == suffix.data() + suffix.size() &&
        rate > 0) {
      return rate;
    }
  }
  return kDefaultFrameRate;
}

class AmcParser {
 public:
  AmcParser(std::string_view text,
            const std::filesystem::path& source,
            const AsfSkeleton& asf,
            const AsfAmcReadOptions& options)
      : source_(source),
        asf_(asf),
        options_(options),
        lines_(SplitIntoLines(text)) {
    const Skeleton& skeleton = asf_.skeleton;
    for (int j = 0; j < skeleton.num_joints(); ++j) {
      if (!skeleton.channels[j].empty())
        joint_index_[ToLower(skeleton.names[j])] = j;
    }
    degrees_ = asf_.angles_in_degrees;
  }

  MotionClip Parse() {
    MotionClip clip;
    clip.name = source_.stem().string();
    clip.source_path = source_.string();
    clip.frame_rate = options_.frame_rate.value_or(InferFrameRate(source_));
    clip.skeleton = asf_.skeleton;
    clip.up_axis = UpAxis::kY;

    const Skeleton& skeleton = asf_.skeleton;
    values_.assign(skeleton.num_joints(), {});
    seen_.assign(skeleton.num_joints(), false);
    for (const Line& line : lines_) {
      const std::string_view first = line.words[0];
      if (first.front() == ':') {
        const std::string key = ToLower(first);
        if (key == ":fully-specified") {
          fully_specified_ = true;
        } else if (key == ":degrees") {
          degrees_ = true;
        } else if (key == ":radians") {
          degrees_ = false;
        } else {
          ThrowAtLine(source_, line.number, "unknown AMC header '{}'", first);
        }
        continue;
      }
      int frame_number = 0;
      const auto [end, error] = std::from_chars(
          first.data(), first.data() + first.size(), frame_number);
      if (line.words.size() == 1 && error == std::errc() &&
          end == first.data() + first.size()) {
        if (in_frame_) FinishFrame(&clip);
        if (in_frame_ && frame_number != frame_number_ + 1) {
          ThrowAtLine(source_,
                      line.number,
                      "frame number {} follows {}; expected consecutive frames",
                      frame_number,
                      frame_number_);
        }
        in_frame_ = true;
        frame_number_ = frame_number;
        frame_line_ = line.number;
        continue;
      }
      if (!in_frame_) {
        ThrowAtLine(
            source_, line.number, "'{}' before the first frame number", first);
      }
      ParseBoneValues(line);
    }
    if (in_frame_) FinishFrame(&clip);
    clip.Validate();
    return clip;
  }

 private:
  void ParseBoneValues(const Line& line) {
    const auto it = joint_index_.find(ToLower(line.words[0]));
    if (it == joint_index_.end()) {
      ThrowAtLine(source_,
                  line.number,
                  "unknown bone '{}' (not a bone with dofs in {})",
                  line.words[0],
                  asf_.source_path);
    }
    const int joint = it->second;
    const std::vector<Channel>& channels = asf_.skeleton.channels[joint];
    if (line.words.size() - 1 != channels.size()) {
      ThrowAtLine(source_,
                  line.number,
                  "bone '{}' has {} values, expected {} (its dofs)",
                  line.words[0],
                  line.words.size() - 1,
                  channels.size());
    }
    if (seen_[joint]) {
      ThrowAtLine(source_,
                  line.number,
                  "bone '{}' appears twice in frame {}",
                  line.words[0],
                  frame_number_);
    }
    seen_[joint] = true;
    std::vector<double>& values = values_[joint];
    values.resize(channels.size());
    for (size_t k = 0; k < channels.size(); ++k) {
      const std::optional<double> value = ParseNumber(line.words[k + 1], false);
      if (!value) {
        ThrowAtLine(source_,
                    line.number,
                    "value {} of bone '{}' is not a number: '{}'",
                    k + 1,
                    line.words[0],
                    line.words[k + 1]);
      }
      values[k] = *value;
    }
  }

  void FinishFrame(MotionClip* clip) {
    const Skeleton& skeleton = asf_.skeleton;
    Eigen::Vector3d root = asf_.root_position;
    std::vector<Eigen::Quaterniond> rotations(skeleton.num_joints(),
                                              Eigen::Quaterniond::Identity());
    std::vector<double> angles;
    for (int j = 0; j < skeleton.num_joints(); ++j) {
      const std::vector<Channel>& channels = skeleton.channels[j];
      if (channels.empty()) continue;
      if (!seen_[j]) {
        if (fully_specified_) {
          ThrowAtLine(source_,
                      frame_line_,
                      "frame {} lacks bone '{}' (file is :FULLY-SPECIFIED)",
                      frame_number_,
                      skeleton.names[j]);
        }
        values_[j].assign(channels.size(), 0.0);
      }
      angles.clear();
      for (size_t c = 0; c < channels.size(); ++c) {
        const double value = values_[j][c];
        if (IsRotation(channels[c].type)) {
          angles.push_back(degrees_ ? value * kDegToRad : value);
        } else {
          root[ChannelAxis(channels[c].type)] += value * asf_.length_to_metres;
        }
      }
      rotations[j] = skeleton.RotationFromChannels(j, angles);
      seen_[j] = false;
    }
    clip->root_translation.push_back(root);
    clip->local_rotations.push_back(std::move(rotations));
  }

  std::filesystem::path source_;
  const AsfSkeleton& asf_;
  AsfAmcReadOptions options_;
  std::vector<Line> lines_;
  std::map<std::string, int> joint_index_;  // lower-case name -> joint
  bool degrees_ = true;
  bool fully_specified_ = false;
  bool in_frame_ = false;
  int frame_number_ = 0;
  int frame_line_ = 0;
  std::vector<std::vector<double>> values_;
  std::vector<bool> seen_;
};

}  // namespace

void AsfAmcReadOptions::Validate() const {
  if (length_to_metres &&
      (!(*length_to_metres > 0.0) || !std::isfinite(*length_to_metres))) {
    throw ConfigError(fmt::format(
        "Invalid configuration. length_to_metres = {}. Violated constraint: "
        "length_to_metres > 0 (AsfAmcReadOptions)",
        *length_to_metres));
  }
  if (frame_rate && (!(*frame_rate > 0.0) || !std::isfinite(*frame_rate))) {
    throw ConfigError(fmt::format(
        "Invalid configuration. frame_rate = {}. Violated constraint: "
        "frame_rate > 0 (AsfAmcReadOptions)",
        *frame_rate));
  }
}

AsfSkeleton ParseAsf(std::string_view text,
                     const std::filesystem::path& source_name,
                     const AsfAmcReadOptions& options) {
  options.Validate();
  return AsfParser(text, source_name, options).Parse();
}

AsfSkeleton ReadAsf(const std::filesystem::path& path,
                    const AsfAmcReadOptions& options) {
  options.Validate();
  const std::string text = ReadFile(path);
  return AsfParser(text, path, options).Parse();
}

MotionClip ParseAmc(std::string_view text,
                    const std::filesystem::path& source_name,
                    const AsfSkeleton& asf,
                    const AsfAmcReadOptions& options) {
  options.Validate();
  return AmcParser(text, source_name, asf, options).Parse();
}

MotionClip ReadAmc(const std::filesystem::path& path,
                   const AsfSkeleton& asf,
                   const AsfAmcReadOptions& options) {
  options.Validate();
  const std::string text = ReadFile(path);
  return AmcParser(text, path, asf, options).Parse();
}

MotionClip ReadAsfAmc(const std::filesystem::path& asf_path,
                      const std::filesystem::path& amc_path,
                      const AsfAmcReadOptions& options) {
  return ReadAmc(amc_path, ReadAsf(asf_path, options), options);
}

}  // namespace soma
