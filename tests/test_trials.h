// Statistical tests under the sanitizers. A coverage test draws hundreds of
// seeded soaks or plants to measure a rate (95 % of intervals cover the
// truth); a sanitized build (scripts/test-sanitizers: ASan+UBSan, TSan) is
// there to find memory and thread errors, which the first few draws reach as
// well as the four-hundredth, at 5-15 times the cost. So in a sanitized build
// such a test runs trials(n) draws, a tenth, and leaves its statistical
// assertions (statistics_checked()) to the plain build, which scripts/test
// runs in full. Every draw's own checks (the analysis succeeds, its result
// is finite) still run.
#pragma once

#include <algorithm>

namespace gyrotherm::testing {

#if defined(__SANITIZE_ADDRESS__) || defined(__SANITIZE_THREAD__)
inline constexpr bool kSanitizedBuild = true;
#elif defined(__has_feature)
#if __has_feature(address_sanitizer) || __has_feature(thread_sanitizer)
inline constexpr bool kSanitizedBuild = true;
#else
inline constexpr bool kSanitizedBuild = false;
#endif
#else
inline constexpr bool kSanitizedBuild = false;
#endif

// n in a plain build; a tenth of it, at least `at_least`, in a sanitized one.
constexpr int trials(int n, int at_least = 8) {
  return kSanitizedBuild ? std::min(n, std::max(at_least, n / 10)) : n;
}

// Whether a statistical test checks its rates: not in a sanitized build,
// whose trials() are too few to.
constexpr bool statistics_checked() { return !kSanitizedBuild; }

}  // namespace gyrotherm::testing
