// The registrations a benchmark executable needs without linking the whole
// framework (tests/bench/CMakeLists.txt): what InitFramework() registers for
// the modules the executable links, in its order, then FreezeRegistries().
// Defined per module in tests/bench/<module>/registrations.cc.
#pragma once

namespace soma::bench {

/// Once per process; later calls return at once.
void RegisterComponents();

}  // namespace soma::bench
