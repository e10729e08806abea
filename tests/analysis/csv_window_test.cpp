// CSV window reader: accepted layouts, each error with its exact message,
// files on disk (a temporary directory) and a round trip of generated rows.
#include "gyrotherm/analysis/csv_window.h"

#include <fmt/format.h>
#include <gtest/gtest.h>
#include <unistd.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <random>
#include <string>
#include <vector>

namespace gyrotherm::analysis {
namespace {

namespace fs = std::filesystem;

// The error message of parsing `text` as "f.csv"; empty if it parsed.
std::string parse_error(std::string_view text) {
  Result<CsvWindow> w = parse_csv_window(text, "f.csv");
  return w.ok() ? std::string() : w.error().message;
}

CsvWindow parse_ok(std::string_view text) {
  Result<CsvWindow> w = parse_csv_window(text, "f.csv");
  EXPECT_TRUE(w.ok()) << w.error().message;
  return w.ok() ? std::move(w).value() : CsvWindow{};
}

class CsvFileTest : public ::testing::Test {
 protected:
  void SetUp() override {
    const auto* info = ::testing::UnitTest::GetInstance()->current_test_info();
    dir_ = fs::temp_directory_path() / fmt::format("gyrotherm_csv_{}_{}", ::getpid(), info->name());
    fs::remove_all(dir_);
    fs::create_directories(dir_);
  }
  void TearDown() override { fs::remove_all(dir_); }

  std::string write(const std::string& name, std::string_view content) {
    const fs::path p = dir_ / name;
    std::ofstream out(p, std::ios::binary);
    out.write(content.data(), static_cast<std::streamsize>(content.size()));
    return p.string();
  }

  fs::path dir_;
};

TEST(CsvWindowParse, ColumnsInAnyOrderWithExtraColumnsIgnored) {
  const CsvWindow w = parse_ok(
      "note,side_c,t_s,seq,rate_dph,top_c\n"
      "start,25.5,0,x,8.25,24.5\n"
      ",25.75,1.5,,-3e-1,24.0\n"
      "not a number either,26,3,,1e2,23.5\n");
  EXPECT_EQ(w.source, "f.csv");
  EXPECT_EQ(w.row_count, 3u);
  EXPECT_EQ(w.t_s, (std::vector<double>{0, 1.5, 3}));
  EXPECT_EQ(w.rate_dph, (std::vector<double>{8.25, -0.3, 100}));
  EXPECT_EQ(w.top_c, (std::vector<double>{24.5, 24.0, 23.5}));
  EXPECT_EQ(w.side_c, (std::vector<double>{25.5, 25.75, 26}));
}

TEST(CsvWindowParse, CrlfBomBlankLinesAndSpaces) {
  const CsvWindow w = parse_ok(
      "\xEF\xBB\xBF\r\n"
      "  \r\n"
      " t_s ,\trate_dph, top_c ,side_c\t\r\n"
      "\r\n"
      "1, 2 ,+3,4\r\n"
      "   \t\r\n"
      "2,-2.5,3.5 ,4.5");  // no final line ending
  EXPECT_EQ(w.row_count, 2u);
  EXPECT_EQ(w.t_s, (std::vector<double>{1, 2}));
  EXPECT_EQ(w.rate_dph, (std::vector<double>{2, -2.5}));
  EXPECT_EQ(w.top_c, (std::vector<double>{3, 3.5}));
  EXPECT_EQ(w.side_c, (std::vector<double>{4, 4.5}));
}

TEST(CsvWindowParse, NonNumbersNameLineAndColumn) {
  EXPECT_EQ(parse_error("t_s,rate_dph,top_c,side_c\n0,1,2,3\n1,abc,2,3\n"),
            "f.csv:3: column rate_dph: 'abc' is not a number");
  EXPECT_EQ(parse_error("t_s,rate_dph,top_c,side_c\n0,1.5x,2,3\n"),
            "f.csv:2: column rate_dph: '1.5x' is not a number");
  EXPECT_EQ(parse_error("t_s,rate_dph,top_c,side_c\n0,1,0x10,3\n"),
            "f.csv:2: column top_c: '0x10' is not a number");
  EXPECT_EQ(parse_error("t_s,rate_dph,top_c,side_c\n0,1,2,+-3\n"),
            "f.csv:2: column side_c: '+-3' is not a number");
  EXPECT_EQ(parse_error("t_s,rate_dph,top_c,side_c\n0,1,2, 3 4\n"),
            "f.csv:2: column side_c: '3 4' is not a number");
  EXPECT_EQ(parse_error("t_s,rate_dph,top_c,side_c\n0,1,2,1e999\n"),
            "f.csv:2: column side_c: '1e999' is out of range for a double");
  EXPECT_EQ(parse_error("t_s,rate_dph,top_c,side_c\n0,1, ,3\n"),
            "f.csv:2: column top_c: empty value");
  const std::string long_field(60, '7');
  EXPECT_EQ(parse_error("t_s,rate_dph,top_c,side_c\n0,1,2,x" + long_field + "\n"),
            "f.csv:2: column side_c: 'x" + long_field.substr(0, 39) + "...' is not a number");
}

TEST(CsvWindowParse, NonFiniteValuesAreErrors) {
  EXPECT_EQ(parse_error("t_s,rate_dph,top_c,side_c\n0,1,nan,3\n"),
            "f.csv:2: column top_c: nan is not finite");
  EXPECT_EQ(parse_error("t_s,rate_dph,top_c,side_c\n0,inf,2,3\n"),
            "f.csv:2: column rate_dph: inf is not finite");
  EXPECT_EQ(parse_error("t_s,rate_dph,top_c,side_c\n-Infinity,1,2,3\n"),
            "f.csv:2: column t_s: -Infinity is not finite");
  EXPECT_EQ(parse_error("t_s,rate_dph,top_c,side_c\n0,1,2,NaN\n"),
            "f.csv:2: column side_c: NaN is not finite");
}

TEST(CsvWindowParse, FieldCountMustMatchTheHeader) {
  EXPECT_EQ(parse_error("t_s,rate_dph,top_c,side_c,note\n0,1,2\n"),
            "f.csv:2: missing value (row has 3 fields, header has 5)");
  EXPECT_EQ(parse_error("t_s,rate_dph,top_c,side_c\n0,1,2,3,\n"),
            "f.csv:2: extra value (row has 5 fields, header has 4)");
}

TEST(CsvWindowParse, TimeMustStrictlyIncrease) {
  EXPECT_EQ(parse_error("t_s,rate_dph,top_c,side_c\n0,1,2,3\n\n1.5,1,2,3\n1.5,1,2,3\n"),
            "f.csv:5: column t_s: 1.5 does not increase (line 4 has 1.5; t_s must be strictly "
            "increasing)");
  EXPECT_EQ(parse_error("t_s,rate_dph,top_c,side_c\n2,1,2,3\n1,1,2,3\n"),
            "f.csv:3: column t_s: 1 does not increase (line 2 has 2; t_s must be strictly "
            "increasing)");
}

TEST(CsvWindowParse, HeaderErrors) {
  EXPECT_EQ(parse_error("t_s,rate_dph,temp\n0,1,2\n"),
            "f.csv:1: header lacks column(s) top_c, side_c (found 't_s', 'rate_dph', 'temp'; "
            "required t_s, rate_dph, top_c, side_c)");
  // Names are case-sensitive; the first non-blank line is the header.
  EXPECT_EQ(parse_error("\n\nT_s,rate_dph,top_c,side_c\n0,1,2,3\n"),
            "f.csv:3: header lacks column(s) t_s (found 'T_s', 'rate_dph', 'top_c', 'side_c'; "
            "required t_s, rate_dph, top_c, side_c)");
  // A file without a header: its first row is taken as one and lacks every name.
  EXPECT_EQ(parse_error("0,1,2,3\n"),
            "f.csv:1: header lacks column(s) t_s, rate_dph, top_c, side_c (found '0', '1', '2', "
            "'3'; required t_s, rate_dph, top_c, side_c)");
  EXPECT_EQ(parse_error("t_s,rate_dph,top_c,side_c,top_c\n0,1,2,3,4\n"),
            "f.csv:1: column top_c appears twice in the header (columns 3 and 5)");
  EXPECT_EQ(parse_error("t_s,\"rate_dph\",top_c,side_c\n0,1,2,3\n"),
            "f.csv:1: quoted fields are not supported (found '\"' in the header)");
}

TEST(CsvWindowParse, QuotesInRowsAreRejected) {
  EXPECT_EQ(parse_error("t_s,rate_dph,top_c,side_c,note\n0,1,2,3,\"a, b\"\n"),
            "f.csv:2: quoted fields are not supported (found '\"')");
}

TEST(CsvWindowParse, EmptyInputs) {
  const std::string no_header =
      "f.csv: no header row (expected a header naming t_s, rate_dph, top_c, side_c)";
  EXPECT_EQ(parse_error(""), no_header);
  EXPECT_EQ(parse_error("\xEF\xBB\xBF"), no_header);
  EXPECT_EQ(parse_error("\r\n \n\t\n"), no_header);
  EXPECT_EQ(parse_error("t_s,rate_dph,top_c,side_c\n"),
            "f.csv: no data rows (only the header, line 1)");
  EXPECT_EQ(parse_error("\nt_s,rate_dph,top_c,side_c\r\n\r\n  \n"),
            "f.csv: no data rows (only the header, line 2)");
}

TEST(CsvWindowParse, ReportsEveryErrorUpToTheCap) {
  // Two errors on one row, one on another: all three, in order.
  EXPECT_EQ(parse_error("t_s,rate_dph,top_c,side_c\n0,a,2,b\n1,1,2,3\n2,1,nan,3\n"),
            "f.csv:2: column rate_dph: 'a' is not a number\n"
            "f.csv:2: column side_c: 'b' is not a number\n"
            "f.csv:4: column top_c: nan is not finite");

  std::string text = "t_s,rate_dph,top_c,side_c\n";
  for (int i = 0; i < 25; ++i) text += fmt::format("{},x,2,3\n", i);
  const std::string msg = parse_error(text);
  std::string expected;
  for (int i = 0; i < 20; ++i) {
    expected += fmt::format("f.csv:{}: column rate_dph: 'x' is not a number\n", i + 2);
  }
  expected += "... and 5 more errors";
  EXPECT_EQ(msg, expected);
}

TEST_F(CsvFileTest, ReadsAFile) {
  const std::string path = write("w.csv", "t_s,rate_dph,top_c,side_c\n0,8,25,26\n1,9,25.5,26.5\n");
  Result<CsvWindow> w = read_csv_window(path);
  ASSERT_TRUE(w.ok()) << w.error().message;
  EXPECT_EQ(w->source, path);
  EXPECT_EQ(w->rate_dph, (std::vector<double>{8, 9}));
}

TEST_F(CsvFileTest, ErrorsNameThePath) {
  const std::string path = write("bad.csv", "t_s,rate_dph,top_c,side_c\n0,8,25,26\n1,9,25.5,\n");
  Result<CsvWindow> w = read_csv_window(path);
  ASSERT_FALSE(w.ok());
  EXPECT_EQ(w.error().message, path + ":3: column side_c: empty value");
  EXPECT_FALSE(w.error().transient);
}

TEST_F(CsvFileTest, MissingFileAndDirectory) {
  const std::string missing = (dir_ / "nope.csv").string();
  Result<CsvWindow> w = read_csv_window(missing);
  ASSERT_FALSE(w.ok());
  EXPECT_EQ(w.error().message,
            fmt::format("cannot open CSV file '{}': No such file or directory", missing));

  Result<CsvWindow> d = read_csv_window(dir_.string());
  ASSERT_FALSE(d.ok());
  EXPECT_NE(d.error().message.find(fmt::format("'{}'", dir_.string())), std::string::npos)
      << d.error().message;
}

TEST_F(CsvFileTest, RoundTripsGeneratedRows) {
  std::mt19937_64 rng(42);
  std::normal_distribution<double> noise(0.0, 1.0);
  const std::size_t n = 5000;
  std::vector<double> t(n), rate(n), top(n), side(n);
  std::string text = "seq,t_s,side_c,rate_dph,top_c\r\n";
  for (std::size_t i = 0; i < n; ++i) {
    t[i] = 1234.5 + 0.1 * static_cast<double>(i) + 1e-7 * noise(rng);
    rate[i] = 8.0 + 0.03 * noise(rng);
    top[i] = 25 + std::sin(static_cast<double>(i) * 1e-3) + 1e-5 * noise(rng);
    side[i] = -40 + 1e-12 * noise(rng);
    // fmt's "{}" is the shortest text that reads back to the same double.
    text += fmt::format("{},{},{},{},{}\r\n", i % 128, t[i], side[i], rate[i], top[i]);
  }
  Result<CsvWindow> w = read_csv_window(write("gen.csv", text));
  ASSERT_TRUE(w.ok()) << w.error().message;
  EXPECT_EQ(w->row_count, n);
  EXPECT_EQ(w->t_s, t);
  EXPECT_EQ(w->rate_dph, rate);
  EXPECT_EQ(w->top_c, top);
  EXPECT_EQ(w->side_c, side);
}

TEST(CsvWindowSeries, SamplesCarryEveryRow) {
  const CsvWindow w = parse_ok("t_s,rate_dph,top_c,side_c\n0,8,25,26\n0.5,9,25.5,26.5\n");
  const CsvSamples s = csv_window_samples(w);
  ASSERT_EQ(s.gyro.size(), 2u);
  ASSERT_EQ(s.temps.size(), 2u);
  EXPECT_EQ(s.gyro[1].t_s, 0.5);
  EXPECT_EQ(s.gyro[1].rate_dph, 9);
  EXPECT_EQ(s.temps[1].t_s, 0.5);
  EXPECT_EQ(s.temps[1].top_c, 25.5);
  EXPECT_EQ(s.temps[1].side_c, 26.5);
  EXPECT_TRUE(std::isnan(s.temps[1].setpoint_c));
  EXPECT_TRUE(std::isnan(s.temps[1].chamber_c));
}

TEST(CsvWindowSeries, OneHertzRowsAreUsedAsIs) {
  const CsvWindow w =
      parse_ok("t_s,rate_dph,top_c,side_c\n10,8,25,26\n11,9,25.5,26.5\n12,7,26,27\n");
  Result<AnalysisSeries> s = csv_analysis_series(w);
  ASSERT_TRUE(s.ok()) << s.error().message;
  EXPECT_FALSE(s->binned);
  EXPECT_DOUBLE_EQ(s->bin_s, 1.0);
  EXPECT_EQ(s->t_s, w.t_s);
  EXPECT_EQ(s->rate_dph, w.rate_dph);
  EXPECT_EQ(s->top_c, w.top_c);
  EXPECT_EQ(s->side_c, w.side_c);
}

TEST(CsvWindowSeries, TenHertzRowsAreBinned) {
  // 10 Hz rows over 3 s: bins of 1 s average 10 rows each (exact in binary:
  // the values are 0..9 plus a per-bin offset, mean offset + 4.5).
  std::string text = "t_s,rate_dph,top_c,side_c\n";
  for (int i = 0; i < 30; ++i) {
    text += fmt::format("{},{},{},{}\n", i / 10.0, 100 * (i / 10) + i % 10, 20 + i % 10, 30);
  }
  Result<AnalysisSeries> s = csv_analysis_series(parse_ok(text), 1.0);
  ASSERT_TRUE(s.ok()) << s.error().message;
  EXPECT_TRUE(s->binned);
  ASSERT_EQ(s->rate_dph.size(), 3u);
  for (std::size_t k = 0; k < 3; ++k) {
    EXPECT_NEAR(s->t_s[k], static_cast<double>(k), 1e-12);
    EXPECT_NEAR(s->rate_dph[k], 100.0 * static_cast<double>(k) + 4.5, 1e-12);
    EXPECT_NEAR(s->top_c[k], 24.5, 1e-12);
    EXPECT_NEAR(s->side_c[k], 30.0, 1e-12);
  }
}

}  // namespace
}  // namespace gyrotherm::analysis
