// CSV helpers shared by every CSV writer of the framework (RFC 4180 quoting).
#pragma once

#include <string>

namespace soma {

/// `field` as one CSV field: quoted (with doubled quotes) when it contains a
/// comma, a quote or a line break; unchanged otherwise.
inline std::string CsvField(const std::string& field) {
  if (field.find_first_of(",\"\r\n") == std::string::npos) return field;
  std::string out = "\"";
  for (char c : field) {
    if (c == '"') out += '"';
    out += c;
  }
  return out + "\"";
}

}  // namespace soma
