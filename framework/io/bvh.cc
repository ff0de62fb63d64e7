#include "framework/io/bvh.h"

#include "framework/core/error.h"
#include "framework/core/file.h"
#include "framework/io/line_error.h"

#include <fmt/format.h>

#include <array>
#include <cctype>
#include <charconv>
#include <cmath>
#include <optional>
#include <string>
#include <vector>

namespace soma {
namespace {

constexpr double kDegToRad = M_PI / 180.0;

struct Token {
  std::string_view text;
  int line = 0;  // 1-based
};

bool IsSpace(char c) {
  return c == ' ' || c == '\t' || c == '\r' || c == '\f' || c == '\v';
}

std::vector<std::string_view> SplitWords(std::string_view line) {
  std::vector<std::string_view> words;
  size_t i = 0;
  while (i < line.size()) {
    while (i < line.size() && IsSpace(line[i])) ++i;
    const size_t start = i;
    while (i < line.size() && !IsSpace(line[i])) ++i;
    if (i > start) words.push_back(line.substr(start, i - start));
  }
  return words;
}

std::vector<std::string_view> SplitLines(std::string_view text) {
  std::vector<std::string_view> lines;
  size_t start = 0;
  while (start <= text.size()) {
    const size_t end = text.find('\n', start);
    if (end == std::string_view::npos) {
      if (start < text.size()) lines.push_back(text.substr(start));
      break;
    }
    lines.push_back(text.substr(start, end - start));
    start = end + 1;
  }
  return lines;
}

std::optional<double> ParseNumber(std::string_view text) {
  if (!text.empty() && text.front() == '+') text.remove_prefix(1);
  double value = 0.0;
  const auto [end, error] =
      std::from_chars(text.data(), text.data() + text.size(), value);
  if (error != std::errc() || end != text.data() + text.size() ||
      !std::isfinite(value)) {
    return std::nullopt;
  }
  return value;
}

std::optional<ChannelType> ParseChannel(std::string_view text) {
  static constexpr std::array<std::pair<std::string_view, ChannelType>, 6>
      kNames = {{{"Xposition", ChannelType::kXPosition},
                 {"Yposition", ChannelType::kYPosition},
                 {"Zposition", ChannelType::kZPosition},
                 {"Xrotation", ChannelType::kXRotation},
                 {"Yrotation", ChannelType::kYRotation},
                 {"Zrotation", ChannelType::kZRotation}}};
  for (const auto& [name, type] : kNames) {
    if (text.size() == name.size()) {
      bool equal = true;  // case-insensitive: some exporters write XPOSITION
      for (size_t i = 0; i < text.size() && equal; ++i) {
        equal = std::tolower(static_cast<unsigned char>(text[i])) ==
                std::tolower(static_cast<unsigned char>(name[i]));
      }
      if (equal) return type;
    }
  }
  return std::nullopt;
}

// A joint as declared in the file (lengths in file units).
struct RawJoint {
  std::string name;
  int parent = -1;
  int line = 0;
  std::optional<Eigen::Vector3d> offset;
  std::vector<ChannelType> channels;
  int first_value = 0;  // index of its first channel in a frame line
};

class BvhParser {
 public:
  BvhParser(std::string_view text,
            const std::filesystem::path& source,
            const BvhReadOptions& options)
      : source_(source), options_(options), lines_(SplitLines(text)) {}

  MotionClip Parse() {
    const int motion_line = TokenizeHierarchy();
    ExpectKeyword("HIERARCHY");
    const Token root = Next("ROOT");
    if (root.text != "ROOT")
      ThrowAtLine(source_, root.line, "expected ROOT, got '{}'", root.text);
    ParseJoint(-1, root.line);
    if (pos_ < tokens_.size()) {
      const Token& extra = tokens_[pos_];
      if (extra.text == "ROOT") {
        ThrowAtLine(
            source_,
            extra.line,
            "a second ROOT; multi-skeleton BVH files are not supported");
      }
      ThrowAtLine(source_,
                  extra.line,
                  "unexpected '{}' after the ROOT block",
                  extra.text);
    }
    if (motion_line < 0) {
      ThrowAtLine(
          source_, static_cast<int>(lines_.size()), "missing MOTION section");
    }
    MotionClip clip = BuildSkeleton();
    ParseMotion(motion_line, clip);
    clip.Validate();
    return clip;
  }

 private:
  // Tokenizes every line before the MOTION line; returns the index of the
  // MOTION line (0-based) or -1.
  int TokenizeHierarchy() {
    for (size_t i = 0; i < lines_.size(); ++i) {
      const std::vector<std::string_view> words = SplitWords(lines_[i]);
      if (!words.empty() && words[0] == "MOTION") {
        if (words.size() > 1) {
          ThrowAtLine(source_,
                      static_cast<int>(i) + 1,
                      "unexpected '{}' after MOTION",
                      words[1]);
        }
        return static_cast<int>(i);
      }
      for (std::string_view word : words) {
        tokens_.push_back({word, static_cast<int>(i) + 1});
      }
    }
    return -1;
  }

  int LastLine() const { return tokens_.empty() ? 1 : tokens_.back().line; }

  Token Next(std::string_view expected) {
    if (pos_ >= tokens_.size()) {
      ThrowAtLine(source_,
                  LastLine(),
                  "unexpected end of HIERARCHY, expected {}",
                  expected);
    }
    return tokens_[pos_++];
  }

  void ExpectKeyword(std::string_view keyword) {
    const Token token = Next(keyword);
    if (token.text != keyword) {
      ThrowAtLine(
          source_, token.line, "expected '{}', got '{}'", keyword, token.text);
    }
  }

  double NextNumber(std::string_view what) {
    const Token token = Next(what);
    const std::optional<double> value = ParseNumber(token.text);
    if (!value)
      ThrowAtLine(source_,
                  token.line,
                  "expected {} (a number), got '{}'",
                  what,
                  token.text);
    return *value;
  }

  Eigen::Vector3d ParseOffset() {
    Eigen::Vector3d offset;
    for (int k = 0; k < 3; ++k) offset[k] = NextNumber("an OFFSET value");
    return offset;
  }

  // After ROOT/JOINT: the name (words up to '{' on the same line), '{', the
  // body and '}'.
  void ParseJoint(int parent, int keyword_line, int depth = 0) {
    // Real skeletons are < 50 deep; this bounds the recursion on bad input.
    constexpr int kMaxDepth = 1000;
    if (depth > kMaxDepth) {
      ThrowAtLine(
          source_, keyword_line, "joints nested deeper than {}", kMaxDepth);
    }
    std::string name;
    while (pos_ < tokens_.size() && tokens_[pos_].line == keyword_line &&
           tokens_[pos_].text != "{") {
      if (!name.empty()) name += ' ';
      name += tokens_[pos_++].text;
    }
    if (name.empty())
      ThrowAtLine(source_, keyword_line, "joint without a name");
    ExpectKeyword("{");
    const int index = static_cast<int>(joints_.size());
    joints_.push_back({name, parent, keyword_line, std::nullopt, {}, 0});
    int end_sites = 0;
    while (true) {
      const Token token = Next("'}'");
      if (token.text == "}") break;
      if (token.text == "OFFSET") {
        if (joints_[index].offset) {
          ThrowAtLine(
              source_, token.line, "joint '{}' has a second OFFSET", name);
        }
        joints_[index].offset = ParseOffset();
      } else if (token.text == "CHANNELS") {
        if (!joints_[index].channels.empty()) {
          ThrowAtLine(source_,
                      token.line,
                      "joint '{}' has a second CHANNELS line",
                      name);
        }
        const double count = NextNumber("the channel count");
        if (count < 0 || count > 6 || count != std::floor(count)) {
          ThrowAtLine(source_,
                      token.line,
                      "channel count {} of joint '{}' not in 0..6",
                      count,
                      name);
        }
        for (int k = 0; k < static_cast<int>(count); ++k) {
          const Token channel = Next("a channel name");
          const std::optional<ChannelType> type = ParseChannel(channel.text);
          if (!type) {
            ThrowAtLine(
                source_,
                channel.line,
                "unknown channel '{}' of joint '{}' (expected Xposition .. "
                "Zrotation)",
                channel.text,
                name);
          }
          if (parent >= 0 && !IsRotation(*type)) {
            ThrowAtLine(
                source_,
                channel.line,
                "joint '{}' has a {} channel; only the ROOT may translate "
                "(unsupported)",
                name,
                channel.text);
          }
          joints_[index].channels.push_back(*type);
        }
      } else if (token.text == "JOINT") {
        ParseJoint(index, token.line, depth + 1);
      } else if (token.text == "End") {
        const Token site = Next("Site");
        if (site.text != "Site")
          ThrowAtLine(source_,
                      site.line,
                      "expected 'End Site', got 'End {}'",
                      site.text);
        ++end_sites;
        ParseEndSite(index, end_sites, site.line);
      } else {
        ThrowAtLine(source_,
                    token.line,
                    "unexpected '{}' in joint '{}'",
                    token.text,
                    name);
      }
    }
    if (!joints_[index].offset) {
      ThrowAtLine(source_, keyword_line, "joint '{}' has no OFFSET", name);
    }
  }

  void ParseEndSite(int parent, int ordinal, int line) {
    ExpectKeyword("{");
    std::string name = joints_[parent].name + "_end";
    if (ordinal > 1) name += std::to_string(ordinal);
    RawJoint joint{name, parent, line, std::nullopt, {}, 0};
    while (true) {
      const Token token = Next("'}'");
      if (token.text == "}") break;
      if (token.text == "OFFSET" && !joint.offset) {
        joint.offset = ParseOffset();
      } else {
        ThrowAtLine(source_,
                    token.line,
                    "unexpected '{}' in End Site of '{}'",
                    token.text,
                    joints_[parent].name);
      }
    }
    if (!joint.offset)
      ThrowAtLine(source_,
                  line,
                  "End Site of '{}' has no OFFSET",
                  joints_[parent].name);
    joints_.push_back(std::move(joint));
  }

  MotionClip BuildSkeleton() {
    MotionClip clip;
    clip.name = source_.stem().string();
    clip.source_path = source_.string();
    clip.up_axis = UpAxis::kY;
    Skeleton& skeleton = clip.skeleton;
    skeleton.euler_convention = EulerConvention::kMovingAxes;
    const double scale = options_.length_to_metres;
    int value_index = 0;
    for (size_t j = 0; j < joints_.size(); ++j) {
      RawJoint& raw = joints_[j];
      if (skeleton.Find(raw.name) >= 0) {
        ThrowAtLine(source_, raw.line, "duplicate joint name '{}'", raw.name);
      }
      skeleton.names.push_back(raw.name);
      skeleton.parents.push_back(raw.parent);
      skeleton.offsets.push_back(j == 0 ? Eigen::Vector3d::Zero().eval()
                                        : (*raw.offset * scale).eval());
      std::vector<Channel> channels;
      for (ChannelType type : raw.channels) channels.push_back({type});
      skeleton.channels.push_back(std::move(channels));
      skeleton.dof_frames.push_back(Eigen::Quaterniond::Identity());
      raw.first_value = value_index;
      value_index += static_cast<int>(raw.channels.size());
    }
    num_values_ = value_index;
    return clip;
  }

  // Finds the next non-blank line at or after `*index`; false at EOF.
  bool NextLine(size_t* index, std::vector<std::string_view>* words) const {
    while (*index < lines_.size()) {
      *words = SplitWords(lines_[*index]);
      if (!words->empty()) return true;
      ++*index;
    }
    return false;
  }

  void ParseMotion(int motion_line, MotionClip& clip) {
    size_t i = static_cast<size_t>(motion_line) + 1;
    std::vector<std::string_view> words;
    // Frames: N
    if (!NextLine(&i, &words))
      ThrowAtLine(source_, motion_line + 1, "missing 'Frames:' after MOTION");
    const int frames_line = static_cast<int>(i) + 1;
    std::optional<double> frames;
    if (words[0] == "Frames:" && words.size() == 2)
      frames = ParseNumber(words[1]);
    if (!frames || *frames < 0 || *frames != std::floor(*frames)) {
      ThrowAtLine(source_,
                  frames_line,
                  "expected 'Frames: <count>', got '{}'",
                  lines_[i]);
    }
    const int num_frames = static_cast<int>(*frames);
    ++i;
    // Frame Time: dt
    if (!NextLine(&i, &words))
      ThrowAtLine(source_, frames_line, "missing 'Frame Time:'");
    std::optional<double> frame_time;
    if (words.size() == 3 && words[0] == "Frame" && words[1] == "Time:") {
      frame_time = ParseNumber(words[2]);
    }
    if (!frame_time || *frame_time <= 0.0) {
      ThrowAtLine(source_,
                  static_cast<int>(i) + 1,
                  "expected 'Frame Time: <seconds>' (positive), got '{}'",
                  lines_[i]);
    }
    double rate = 1.0 / *frame_time;
    if (std::abs(rate - std::round(rate)) < 0.005) rate = std::round(rate);
    clip.frame_rate = rate;
    ++i;

    const Skeleton& skeleton = clip.skeleton;
    const double scale = options_.length_to_metres;
    const Eigen::Vector3d root_offset = *joints_[0].offset;
    clip.root_translation.reserve(num_frames);
    clip.local_rotations.reserve(num_frames);
    std::vector<double> values(num_values_);
    std::vector<double> angles;
    int frame = 0;
    while (NextLine(&i, &words)) {
      const int line = static_cast<int>(i) + 1;
      if (frame == num_frames) {
        ThrowAtLine(source_,
                    line,
                    "more frame lines than 'Frames: {}' (line {}) announces",
                    num_frames,
                    frames_line);
      }
      if (static_cast<int>(words.size()) != num_values_) {
        ThrowAtLine(source_,
                    line,
                    "frame {} has {} values, expected {} (one per channel)",
                    frame,
                    words.size(),
                    num_values_);
      }
      for (int k = 0; k < num_values_; ++k) {
        const std::optional<double> value = ParseNumber(words[k]);
        if (!value) {
          ThrowAtLine(source_,
                      line,
                      "frame {} value {} is not a number: '{}'",
                      frame,
                      k + 1,
                      words[k]);
        }
        values[k] = *value;
      }
      Eigen::Vector3d root = root_offset;
      std::vector<Eigen::Quaterniond> rotations(skeleton.num_joints());
      for (int j = 0; j < skeleton.num_joints(); ++j) {
        const RawJoint& raw = joints_[j];
        angles.clear();
        for (size_t c = 0; c < raw.channels.size(); ++c) {
          const double value = values[raw.first_value + c];
          if (IsRotation(raw.channels[c])) {
            angles.push_back(value * kDegToRad);
          } else {
            root[ChannelAxis(raw.channels[c])] += value;
          }
        }
        rotations[j] = angles.empty()
                           ? Eigen::Quaterniond::Identity()
                           : skeleton.RotationFromChannels(j, angles);
      }
      clip.root_translation.push_back(root * scale);
      clip.local_rotations.push_back(std::move(rotations));
      ++frame;
      ++i;
    }
    if (frame < num_frames) {
      ThrowAtLine(source_,
                  static_cast<int>(lines_.size()),
                  "file ends after {} of {} frames ('Frames:' at line {})",
                  frame,
                  num_frames,
                  frames_line);
    }
  }

  std::filesystem::path source_;
  BvhReadOptions options_;
  std::vector<std::string_view> lines_;
  std::vector<Token> tokens_;
  size_t pos_ = 0;
  std::vector<RawJoint> joints_;
  int num_values_ = 0;
};

}  // namespace

void BvhReadOptions::Validate() const {
  if (!(length_to_metres > 0.0) || !std::isfinite(length_to_metres)) {
    throw ConfigError(fmt::format(
        "Invalid configuration. length_to_metres = {}. Violated constraint: "
        "length_to_metres > 0 (BvhReadOptions)",
        length_to_metres));
  }
}

MotionClip ParseBvh(std::string_view text,
                    const std::filesystem::path& source_name,
                    const BvhReadOptions& options) {
  options.Validate();
  return BvhParser(text, source_name, options).Parse();
}

MotionClip ReadBvh(const std::filesystem::path& path,
                   const BvhReadOptions& options) {
  options.Validate();
  const std::string text = ReadFile(path);
  return BvhParser(text, path, options).Parse();
}

}  // namespace soma
