// One acquisition window read from a CSV file, for the offline analysis
// commands (`gyrotherm stats|allan|fit --csv FILE`). A CSV is one window.
//
// Format:
// - The first non-blank line is the header. A UTF-8 BOM before it is skipped.
//   It names at least the columns t_s, rate_dph, top_c, side_c (station
//   seconds, °/h, °C, °C), in any order; names are trimmed of spaces and tabs
//   and compared exactly (case-sensitive). Other columns are ignored and their
//   values not parsed. A required name given twice is an error.
// - Separator ',', lines end in LF or CRLF, blank (or all-blank) lines are
//   skipped. Quotes are not supported: a '"' anywhere is an error, rather than
//   a field split at a quoted comma.
// - Every data row has as many fields as the header. Each required field,
//   trimmed of spaces and tabs (and one leading '+'), must parse completely as
//   a finite double (std::from_chars, general format: "1.5", "-2e-3", no hex).
// - t_s strictly increases from row to row.
//
// Errors are permanent and name the source, the line (1-based, blank lines
// counted) and the column, e.g.
//   run7.csv:12: column rate_dph: 'abc' is not a number
//   run7.csv:13: column top_c: nan is not finite
//   run7.csv:14: missing value (row has 3 fields, header has 5)
// Every row is checked; the message lists the first kMaxCsvErrors errors, one
// per line, then "... and N more errors". A file with errors gives no data.
#pragma once

#include <cstddef>
#include <span>
#include <string>
#include <string_view>
#include <vector>

#include "gyrotherm/analysis/table1.h"
#include "gyrotherm/core/result.h"
#include "gyrotherm/core/samples.h"

namespace gyrotherm::analysis {

inline constexpr std::size_t kMaxCsvErrors = 20;

// The required columns, one vector per column, one element per data row.
struct CsvWindow {
  std::string source;  // the path or name used in messages
  std::size_t row_count = 0;
  std::vector<double> t_s;       // station seconds, strictly increasing
  std::vector<double> rate_dph;  // °/h
  std::vector<double> top_c;     // °C
  std::vector<double> side_c;    // °C
};

// Parses `text` (the whole file's bytes); `source_name` prefixes the messages.
Result<CsvWindow> parse_csv_window(std::string_view text, const std::string& source_name);

// Reads the file in one go and parses it (the path is the source name).
// Errors: the file cannot be opened or read (names the path and the system's
// reason), then those of parse_csv_window. Memory: the file's size plus
// 32 bytes per row; a 10 M-row file (480 MB) parses in about 2 s.
Result<CsvWindow> read_csv_window(const std::string& path);

// A CSV row is both a gyro sample and a temperature sample at the same t_s.
struct CsvSamples {
  std::vector<GyroSample> gyro;          // t_s, rate_dph; seq, status, temp_c 0
  std::vector<TemperatureSample> temps;  // t_s, top_c, side_c; setpoint_c and chamber_c NaN
};
CsvSamples csv_window_samples(const CsvWindow& window);

// The analysis series of the window for Table I statistics and the drift-model
// fit (stats, fit): make_analysis_series(csv_window_samples(window), bin_s),
// i.e. the same rules as a window read from the database. Rows spaced
// >= bin_s (a CSV already at 1 Hz, or a series exported by `gyrotherm
// export`) are used as is, each row keeping its own temperatures exactly;
// faster rows (raw 10 Hz gyro data) are averaged into bins of bin_s, the
// temperatures over the same bins. The Allan deviation is computed on the
// samples as recorded: pass window.t_s and window.rate_dph to allan_deviation.
// Errors: those of make_analysis_series (only a bad bin_s, once parsed).
Result<AnalysisSeries> csv_analysis_series(const CsvWindow& window, double bin_s = 1.0);

// ---- Any named numeric columns ----------------------------------------------
// The same reader for other tables (the scale-factor points of
// `gyrotherm scale-factor --csv`): the format rules above, with the columns
// the caller names instead of t_s, rate_dph, top_c, side_c, and no ordering
// rule between rows. Required columns must be in the header (the message
// lists them); optional ones may be absent, and then nothing is read for
// them. Every value read must be a finite number, as above.

struct CsvColumn {
  std::string_view name;
  bool required = true;
};

struct CsvColumns {
  std::string source;
  std::size_t row_count = 0;
  std::vector<std::size_t> line;  // 1-based file line of each data row
  // One entry per column asked for, in the order asked.
  std::vector<bool> present;
  std::vector<std::vector<double>> values;  // one per data row; empty when absent
};

Result<CsvColumns> parse_csv_columns(std::string_view text, const std::string& source_name,
                                     std::span<const CsvColumn> columns);
// Reads the file in one go (errors as read_csv_window's), then parses it.
Result<CsvColumns> read_csv_columns(const std::string& path, std::span<const CsvColumn> columns);

}  // namespace gyrotherm::analysis
