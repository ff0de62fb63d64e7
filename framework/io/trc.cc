#include "framework/io/trc.h"

#include "framework/core/error.h"
#include "framework/core/file.h"
#include "framework/core/logging.h"
#include "framework/io/line_error.h"

#include <fmt/format.h>

#include <charconv>
#include <cmath>
#include <limits>
#include <optional>

namespace soma {
namespace {

constexpr float kNaN = std::numeric_limits<float>::quiet_NaN();

struct Line {
  int number = 0;  // 1-based
  std::string_view text;
};

std::vector<Line> SplitLines(std::string_view text) {
  std::vector<Line> lines;
  int number = 0;
  size_t begin = 0;
  while (begin <= text.size()) {
    size_t end = text.find('\n', begin);
    if (end == std::string_view::npos) end = text.size();
    std::string_view line = text.substr(begin, end - begin);
    if (!line.empty() && line.back() == '\r') line.remove_suffix(1);
    ++number;
    if (end == text.size() && line.empty()) break;  // no trailing empty line
    lines.push_back({number, line});
    begin = end + 1;
  }
  return lines;
}

std::string_view TrimView(std::string_view s) {
  while (!s.empty() && (s.front() == ' ' || s.front() == '\t')) {
    s.remove_prefix(1);
  }
  while (!s.empty() && (s.back() == ' ' || s.back() == '\t')) {
    s.remove_suffix(1);
  }
  return s;
}

bool IsBlankLine(std::string_view s) {
  for (char c : s) {
    if (c != ' ' && c != '\t') return false;
  }
  return true;
}

// Tab-separated cells, each trimmed of blanks.
void SplitCells(std::string_view line, std::vector<std::string_view>& cells) {
  cells.clear();
  size_t begin = 0;
  while (true) {
    const size_t tab = line.find('\t', begin);
    if (tab == std::string_view::npos) {
      cells.push_back(TrimView(line.substr(begin)));
      return;
    }
    cells.push_back(TrimView(line.substr(begin, tab - begin)));
    begin = tab + 1;
  }
}

bool EqualsIgnoreCase(std::string_view a, std::string_view b) {
  if (a.size() != b.size()) return false;
  for (size_t i = 0; i < a.size(); ++i) {
    auto lower = [](char c) {
      return (c >= 'A' && c <= 'Z') ? static_cast<char>(c - 'A' + 'a') : c;
    };
    if (lower(a[i]) != lower(b[i])) return false;
  }
  return true;
}

bool IsNanText(std::string_view cell) {
  return EqualsIgnoreCase(cell, "nan") || EqualsIgnoreCase(cell, "-nan") ||
         EqualsIgnoreCase(cell, "+nan");
}

class TrcParser {
 public:
  TrcParser(std::string_view source, const TrcReadOptions& options)
      : source_(source), options_(options) {}

  [[noreturn]] void Fail(int line, std::string_view message) const {
    throw IoError(fmt::format(
        "Invalid TRC file '{}' line {}: {}", source_, line, message));
  }

  // A number, or nullopt for a blank / NaN cell.
  std::optional<double> Number(std::string_view cell,
                               int line,
                               size_t column) const {
    if (cell.empty() || IsNanText(cell)) return std::nullopt;
    std::string_view digits = cell;
    if (digits.front() == '+') digits.remove_prefix(1);
    double value = 0.0;
    const auto [end, ec] =
        std::from_chars(digits.data(), digits.data() + digits.size(), value);
    if (ec != std::errc() || end != digits.data() + digits.size()) {
      Fail(
          line,
          fmt::format(
              "column {}: '{}' is not a number", column + 1, ForMessage(cell)));
    }
    return value;
  }

  double RequiredNumber(const std::map<std::string, std::string>& header,
                        std::string_view key,
                        int line) const {
    const auto it = header.find(std::string(key));
    if (it == header.end()) {
      Fail(line, fmt::format("the header has no '{}'", key));
    }
    const auto value = ParseHeaderNumber(it->second);
    if (!value) {
      Fail(line,
           fmt::format(
               "{} is '{}', expected a number", key, ForMessage(it->second)));
    }
    return *value;
  }

  // A finite number filling the whole cell, else nullopt.
  static std::optional<double> ParseHeaderNumber(std::string_view text) {
    double value = 0.0;
    const auto [end, ec] =
        std::from_chars(text.data(), text.data() + text.size(), value);
    if (text.empty() || ec != std::errc() || end != text.data() + text.size() ||
        !std::isfinite(value)) {
      return std::nullopt;
    }
    return value;
  }

  int Count(const std::map<std::string, std::string>& header,
            std::string_view key,
            int line) const {
    const double value = RequiredNumber(header, key, line);
    if (value < 0 || value > std::numeric_limits<int>::max() ||
        value != std::floor(value)) {
      Fail(line, fmt::format("{} is {}, expected a count", key, value));
    }
    return static_cast<int>(value);
  }

  double Optional(const std::map<std::string, std::string>& header,
                  std::string_view key) const {
    const auto it = header.find(std::string(key));
    if (it == header.end()) return 0.0;
    return ParseHeaderNumber(it->second).value_or(0.0);
  }

  // An optional integer entry, 0 if absent, not a number or out of range.
  int OptionalInt(const std::map<std::string, std::string>& header,
                  std::string_view key) const {
    const double value = Optional(header, key);
    return std::fabs(value) < std::numeric_limits<int>::max()
               ? static_cast<int>(value)
               : 0;
  }

  TrcData Parse(std::string_view text) {
    TrcData data;
    data.source = std::string(source_);
    const std::vector<Line> lines = SplitLines(text);
    std::vector<std::string_view> cells;

    // Line 1: PathFileType.
    if (lines.empty()) Fail(1, "the file is empty");
    SplitCells(lines[0].text, cells);
    if (!EqualsIgnoreCase(cells[0], "PathFileType")) {
      Fail(1,
           fmt::format("starts with '{}', expected 'PathFileType'",
                       ForMessage(cells[0])));
    }
    // Lines 2-3: keys and values.
    if (lines.size() < 3)
      Fail(static_cast<int>(lines.size()) + 1,
           "the header ends before the key/value lines");
    std::vector<std::string_view> keys;
    SplitCells(lines[1].text, keys);
    SplitCells(lines[2].text, cells);
    for (size_t i = 0; i < keys.size() && i < cells.size(); ++i) {
      if (!keys[i].empty()) {
        data.header.emplace(std::string(keys[i]), std::string(cells[i]));
      }
    }
    const int values_line = lines[2].number;
    data.frame_rate = RequiredNumber(data.header, "DataRate", values_line);
    if (data.frame_rate <= 0.0) {
      Fail(values_line,
           fmt::format("DataRate is {}, expected > 0", data.frame_rate));
    }
    const int declared_frames = Count(data.header, "NumFrames", values_line);
    const int num_markers = Count(data.header, "NumMarkers", values_line);
    const auto units = data.header.find("Units");
    if (units == data.header.end() || units->second.empty()) {
      Fail(values_line, "the header has no 'Units'");
    }
    data.units = units->second;
    data.camera_rate = Optional(data.header, "CameraRate");
    data.orig_data_rate = Optional(data.header, "OrigDataRate");
    data.orig_data_start_frame = OptionalInt(data.header, "OrigDataStartFrame");
    data.orig_num_frames = OptionalInt(data.header, "OrigNumFrames");

    // Line 4: Frame# Time <names>; line 5: X1 Y1 Z1 ... (skipped).
    if (lines.size() < 5) {
      Fail(static_cast<int>(lines.size()) + 1,
           "the header ends before the marker-name lines");
    }
    SplitCells(lines[3].text, cells);
    if (cells.size() < 2 || !EqualsIgnoreCase(cells[0], "Frame#")) {
      Fail(lines[3].number, "expected 'Frame#' and 'Time' columns");
    }
    for (size_t i = 2; i < cells.size(); ++i) {
      if (!cells[i].empty()) data.labels.emplace_back(cells[i]);
    }
    if (static_cast<int>(data.labels.size()) != num_markers) {
      Fail(lines[3].number,
           fmt::format("NumMarkers is {} but the line names {} markers",
                       num_markers,
                       data.labels.size()));
    }
    data.num_markers = num_markers;

    // Data rows.
    const size_t columns = 2 + 3 * static_cast<size_t>(num_markers);
    std::vector<float> values;
    std::vector<uint8_t> valid;
    int last_line = lines[4].number;
    for (size_t i = 5; i < lines.size(); ++i) {
      const Line& line = lines[i];
      if (IsBlankLine(line.text)) continue;
      last_line = line.number;
      SplitCells(line.text, cells);
      if (cells.size() < columns) {
        Fail(line.number,
             fmt::format("truncated row: {} cells, expected {} (Frame#, "
                         "Time and X/Y/Z of {} markers)",
                         cells.size(),
                         columns,
                         num_markers));
      }
      for (size_t c = columns; c < cells.size(); ++c) {
        if (!cells[c].empty()) {
          Fail(line.number,
               fmt::format("column {}: unexpected value '{}' after the {} "
                           "marker columns",
                           c + 1,
                           ForMessage(cells[c]),
                           num_markers));
        }
      }
      const auto frame = Number(cells[0], line.number, 0);
      if (!frame || *frame != std::floor(*frame) ||
          std::fabs(*frame) > std::numeric_limits<int>::max()) {
        Fail(line.number,
             fmt::format("column 1: frame number '{}' is not an integer",
                         ForMessage(cells[0])));
      }
      const auto time = Number(cells[1], line.number, 1);
      if (!time) Fail(line.number, "column 2: the time is missing");
      data.frame_numbers.push_back(static_cast<int>(*frame));
      data.times.push_back(*time);
      for (int m = 0; m < num_markers; ++m) {
        const size_t c0 = 2 + 3 * static_cast<size_t>(m);
        const auto x = Number(cells[c0], line.number, c0);
        const auto y = Number(cells[c0 + 1], line.number, c0 + 1);
        const auto z = Number(cells[c0 + 2], line.number, c0 + 2);
        const bool ok = x && y && z && std::isfinite(*x) && std::isfinite(*y) &&
                        std::isfinite(*z);
        values.push_back(ok ? static_cast<float>(*x) : kNaN);
        values.push_back(ok ? static_cast<float>(*y) : kNaN);
        values.push_back(ok ? static_cast<float>(*z) : kNaN);
        valid.push_back(ok ? 1 : 0);
      }
    }
    const int rows = static_cast<int>(data.times.size());
    if (rows < declared_frames) {
      if (!options_.allow_truncated) {
        Fail(last_line,
             fmt::format("NumFrames is {} but the file ends after {} data "
                         "rows",
                         declared_frames,
                         rows));
      }
      SOMA_LOG(WARNING,
               "Truncated TRC file '{}': {} of {} declared frames",
               source_,
               rows,
               declared_frames);
    } else if (rows > declared_frames) {
      SOMA_LOG(WARNING,
               "TRC file '{}': NumFrames is {} but it has {} data rows; "
               "reading all rows",
               source_,
               declared_frames,
               rows);
    }
    data.num_frames = rows;
    data.points = Eigen::Map<const C3dMatrix>(
        values.data(), rows, 3 * static_cast<Eigen::Index>(num_markers));
    data.valid.resize(rows, num_markers);
    for (Eigen::Index i = 0; i < data.valid.size(); ++i) {
      data.valid.data()[i] = valid[i] != 0;
    }
    return data;
  }

 private:
  std::string_view source_;
  const TrcReadOptions& options_;
};

}  // namespace

TrcData ParseTrc(std::string_view text,
                 std::string_view source_name,
                 const TrcReadOptions& options) {
  return TrcParser(source_name, options).Parse(text);
}

TrcData ReadTrc(const std::filesystem::path& path,
                const TrcReadOptions& options) {
  std::error_code ec;
  if (!std::filesystem::is_regular_file(path, ec)) {
    throw IoError(fmt::format("Cannot read TRC file '{}': {}",
                              path.string(),
                              ec ? ec.message() : "not a regular file"));
  }
  const std::string text = ReadFile(path);
  return ParseTrc(text, path.string(), options);
}

}  // namespace soma
