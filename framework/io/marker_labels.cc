#include "framework/io/marker_labels.h"

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

}  // namespace soma
