// Marker label helpers shared by every reader (C3D, TRC) and layout code.
#pragma once

#include <string_view>

namespace soma {

/// `meinard:LFHD` -> `LFHD`: the text after the last ':', trimmed of blanks
/// and NULs (C3D labels are blank padded); labels without a prefix are only
/// trimmed.
std::string_view StripSubjectPrefix(std::string_view label);

}  // namespace soma
