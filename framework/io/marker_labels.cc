#include "framework/io/marker_labels.h"

#include <array>
#include <map>

namespace soma {

std::string_view StripSubjectPrefix(std::string_view label) {
  const size_t colon = label.rfind(':');
  if (colon != std::string_view::npos) label.remove_prefix(colon + 1);
  auto blank = [](char c) {
    return c == ' ' || c == '\t' || c == '\0' || c == '\r' || c == '\n';
  };
  while (!label.empty() && blank(label.front())) label.remove_prefix(1);
  while (!label.empty() && blank(label.back())) label.remove_suffix(1);
  return label;
}

namespace {

// Plug-in Gait's segments: unsided, and sided (prefixed L or R).
constexpr std::array<std::string_view, 3> kPigUnsidedSegments = {
    "PEL", "HED", "TRX"};
constexpr std::array<std::string_view, 8> kPigSidedSegments = {
    "CL", "FE", "FO", "HN", "HU", "RA", "TI", "TO"};
constexpr std::string_view kPigAxes = "OALP";  // origin first

// The segment of a virtual-point name (`LFEA` -> `LFE`), or "" when `name`
// is not `<segment><axis>`.
std::string_view PigSegment(std::string_view name) {
  if (name.size() < 4 || kPigAxes.find(name.back()) == std::string_view::npos)
    return {};
  const std::string_view segment = name.substr(0, name.size() - 1);
  for (std::string_view s : kPigUnsidedSegments) {
    if (segment == s) return segment;
  }
  if (segment.size() == 3 && (segment[0] == 'L' || segment[0] == 'R')) {
    for (std::string_view s : kPigSidedSegments) {
      if (segment.substr(1) == s) return segment;
    }
  }
  return {};
}

}  // namespace

std::vector<bool> PlugInGaitVirtualPoints(std::span<const std::string> labels) {
  // Per segment: which of its axes O, A, L, P the labels hold.
  std::map<std::string_view, std::array<bool, 4>> axes;
  for (const std::string& label : labels) {
    const std::string_view name = StripSubjectPrefix(label);
    const std::string_view segment = PigSegment(name);
    if (segment.empty()) continue;
    axes[segment][kPigAxes.find(name.back())] = true;
  }
  std::vector<bool> is_virtual(labels.size(), false);
  for (size_t i = 0; i < labels.size(); ++i) {
    const std::string_view name = StripSubjectPrefix(labels[i]);
    if (name == "CentreOfMass" || name == "CentreOfMassFloor") {
      is_virtual[i] = true;
      continue;
    }
    const std::string_view segment = PigSegment(name);
    if (segment.empty()) continue;
    const std::array<bool, 4>& present = axes.at(segment);
    is_virtual[i] =
        present[0] && int{present[1]} + present[2] + present[3] >= 2;
  }
  return is_virtual;
}

}  // namespace soma
