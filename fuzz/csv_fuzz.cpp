// Fuzzes the CSV window reader (analysis/csv_window.h, parse_csv_window) and
// what the offline commands do next with its result (csv_window_samples,
// csv_analysis_series). A refused file is fine, with a message; an accepted
// one must hold the format's promises: equal column lengths, finite values,
// t_s strictly increasing.
#include <cmath>
#include <string>
#include <string_view>

#include "fuzz_check.h"
#include "gyrotherm/analysis/csv_window.h"

using namespace gyrotherm::analysis;

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const std::string_view text(reinterpret_cast<const char*>(data), size);
  const auto w = parse_csv_window(text, "fuzz.csv");
  if (!w.ok()) {
    FUZZ_CHECK(!w.error().message.empty());
    return 0;
  }
  const std::size_t n = w->row_count;
  FUZZ_CHECK(w->t_s.size() == n && w->rate_dph.size() == n && w->top_c.size() == n &&
             w->side_c.size() == n);
  for (std::size_t i = 0; i < n; ++i) {
    FUZZ_CHECK(std::isfinite(w->t_s[i]) && std::isfinite(w->rate_dph[i]) &&
               std::isfinite(w->top_c[i]) && std::isfinite(w->side_c[i]));
    if (i > 0) FUZZ_CHECK(w->t_s[i] > w->t_s[i - 1]);
  }
  const CsvSamples samples = csv_window_samples(*w);
  FUZZ_CHECK(samples.gyro.size() == n && samples.temps.size() == n);
  const auto series = csv_analysis_series(*w, 1.0);
  (void)series;  // an error is fine (e.g. too few rows); a crash is not
  return 0;
}
