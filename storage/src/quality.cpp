// The quality columns of the result tables (schema v11; ResultQuality).
#include <nlohmann/json.hpp>

#include "duts_internal.h"

namespace gyrotherm::storage::internal {

void bind_quality(Stmt& st, int first, const ResultQuality& q) {
  int i = first;
  if (q.verdict == "unassessed") {
    st.bind_null(i++);
  } else {
    st.bind(i++, q.samples);
  }
  st.bind(i++, q.expected > 0 ? std::optional<double>(q.expected) : std::nullopt);
  st.bind(i++, q.coverage);
  st.bind(i++, q.longest_gap_s);
  st.bind(i++, std::string_view(q.verdict));
  st.bind(i++, std::string_view(strings_json(q.reasons)));
}

ResultQuality read_quality(const Stmt& st, int first) {
  ResultQuality q;
  int c = first;
  q.samples = st.column_optional_int64(c++).value_or(0);
  q.expected = st.column_optional_double(c++).value_or(0.0);
  q.coverage = st.column_optional_double(c++);
  q.longest_gap_s = st.column_optional_double(c++);
  q.verdict = st.column_text(c++);
  const std::string reasons = st.column_text(c++);
  if (auto list = strings_from_json(reasons, "quality_reasons_json")) {
    q.reasons = std::move(*list);
  } else {
    q.reasons = {list.error().message};
  }
  return q;
}

}  // namespace gyrotherm::storage::internal
