// Coefficient export: the JSON round-trips every number exactly; the C99
// headers compile (cc -std=c99 -Wall -Wextra -pedantic -Werror) and a tiny C
// program using them agrees with drift_terms / coefficients_at to 1e-12
// relative (of the size of the terms: sum of |coefficient x power|, which
// bounds the rounding of either evaluation).
#include <fmt/format.h>
#include <gtest/gtest.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "gyrotherm/analysis/start_temperature.h"
#include "multirun_data.h"
#include "test_files.h"

namespace gyrotherm::analysis {
namespace {

using gyrotherm::testing::read_text;
using testing::load_runs;
using testing::read_reference_lines;

const char* const kScript = "tools/reference/multirun_reference.py";

std::vector<AnalysisSeries> start_runs() {
  return load_runs(read_reference_lines("start_temperature_cubic.txt", kScript));
}

DriftFit pooled_fit(DriftModelForm form) {
  const std::vector<AnalysisSeries> runs =
      load_runs(read_reference_lines("comparison_grid.txt", kScript));
  auto fit = fit_drift_model(runs, *parse_model_spec("T4+R1+G1"), form);
  EXPECT_TRUE(fit.ok()) << fit.error().message;
  return *fit;
}

const ExportInfo kInfo = {.station = "bench-1",
                          .gyro_serial = "FOG-0042",
                          .run_ids = {12, 13, 15},
                          .computed_utc = "2026-05-21T10:00:00Z",
                          .l0_window_s = 120.0};

TEST(CoefficientExport, DriftFitJsonRoundTripsExactly) {
  for (DriftModelForm form : {DriftModelForm::kPaper, DriftModelForm::kCentered}) {
    const DriftFit fit = pooled_fit(form);
    const nlohmann::json j = nlohmann::json::parse(drift_fit_json(fit, kInfo));
    EXPECT_EQ(j.at("model"), "T4+R1+G1");
    EXPECT_EQ(j.at("form"), std::string(to_string(form)));
    ASSERT_EQ(j.at("coefficients").size(), fit.coefficients.size());
    for (const auto& [name, value] : fit.coefficients) {
      EXPECT_EQ(j.at("coefficients").at(name).get<double>(), value) << name;  // bit for bit
      EXPECT_EQ(j.at("std_errors").at(name).get<double>(), fit.std_errors.at(name)) << name;
    }
    EXPECT_EQ(j.at("residual_std_dph").get<double>(), fit.residual_std_dph);
    EXPECT_EQ(j.at("r_squared").get<double>(), fit.r_squared);
    EXPECT_EQ(j.at("l0_dph").get<double>(), fit.l0_dph);
    EXPECT_EQ(j.at("derivative_window_s").get<double>(), fit.derivative_window_s);
    EXPECT_EQ(j.at("l0_window_s").get<double>(), 120.0);
    EXPECT_EQ(j.at("n").get<std::size_t>(), fit.n);
    EXPECT_EQ(j.at("runs"), nlohmann::json::array({12, 13, 15}));
    EXPECT_EQ(j.at("station"), "bench-1");
    EXPECT_EQ(j.at("gyro_serial"), "FOG-0042");
    EXPECT_TRUE(j.at("units").contains("rate"));
  }
}

TEST(CoefficientExport, StartModelJsonRoundTripsExactly) {
  auto model = fit_start_temperature_model(start_runs());
  ASSERT_TRUE(model.ok()) << model.error().message;
  const nlohmann::json j = nlohmann::json::parse(start_model_json(*model, kInfo));
  EXPECT_EQ(j.at("model"), "T4+R1+G1");
  ASSERT_EQ(j.at("cubic").size(), model->cubic.size());
  for (const auto& [name, a] : model->cubic) {
    for (std::size_t k = 0; k < 4; ++k) {
      EXPECT_EQ(j.at("cubic").at(name).at(k).get<double>(), a[k]) << name << " A" << k;
    }
    EXPECT_EQ(j.at("cubic_residual_std").at(name).get<double>(),
              model->cubic_residual_std.at(name));
  }
  ASSERT_EQ(j.at("t0_c").size(), model->t0_c.size());
  for (std::size_t r = 0; r < model->t0_c.size(); ++r) {
    EXPECT_EQ(j.at("t0_c").at(r).get<double>(), model->t0_c[r]);
    for (const auto& [name, v] : model->run_coefficients[r]) {
      EXPECT_EQ(j.at("run_coefficients").at(r).at(name).get<double>(), v) << r << " " << name;
    }
  }
}

// ---- C header --------------------------------------------------------------

std::string find_c_compiler() {
  if (const char* cc = std::getenv("CC"); cc != nullptr && *cc != '\0') return cc;
  for (const char* cc : {"cc", "gcc", "clang"}) {
    if (std::system(fmt::format("command -v {} >/dev/null 2>&1", cc).c_str()) == 0) return cc;
  }
  return "";
}

struct TempDir {
  std::filesystem::path path;
  TempDir() {
    std::string tmpl =
        (std::filesystem::temp_directory_path() / "gyrotherm-export-XXXXXX").string();
    if (mkdtemp(tmpl.data()) != nullptr) path = tmpl;
  }
  ~TempDir() {
    std::error_code ec;
    if (!path.empty()) std::filesystem::remove_all(path, ec);
  }
};

void write_file(const std::filesystem::path& p, const std::string& text) {
  std::ofstream(p) << text;
}

// Compiles main.c in `dir` against the headers there and returns its stdout
// (one number a line), or fails the test.
std::vector<double> compile_and_run(const std::string& cc, const std::filesystem::path& dir) {
  const std::string exe = (dir / "prog").string();
  const std::string compile =
      fmt::format("{} -std=c99 -Wall -Wextra -pedantic -Werror -O2 -o '{}' '{}' -lm 2>'{}'", cc,
                  exe, (dir / "main.c").string(), (dir / "cc.log").string());
  if (std::system(compile.c_str()) != 0) {
    ADD_FAILURE() << "C compile failed: " << compile << "\n" << read_text(dir / "cc.log");
    return {};
  }
  std::vector<double> out;
  FILE* pipe = popen(exe.c_str(), "r");
  if (pipe == nullptr) {
    ADD_FAILURE() << "cannot run " << exe;
    return out;
  }
  char line[128];
  while (std::fgets(line, sizeof line, pipe) != nullptr) out.push_back(std::strtod(line, nullptr));
  EXPECT_EQ(pclose(pipe), 0);
  return out;
}

struct Inputs {
  std::vector<double> t, r, g;
};

Inputs variables(const AnalysisSeries& s, double window_s) {
  Inputs in;
  for (std::size_t i = 0; i < s.t_s.size(); ++i) in.t.push_back((s.top_c[i] + s.side_c[i]) / 2);
  in.r = smoothing_derivative(s.t_s, in.t, window_s);
  for (std::size_t i = 0; i < s.t_s.size(); ++i) in.g.push_back(s.top_c[i] - s.side_c[i]);
  return in;
}

// Sum of |coefficient x power| over the terms at one point.
double term_size(const std::map<std::string, double>& c, double t, double r, double g) {
  double size = 0;
  for (const auto& [name, v] : c) {
    if (name == "intercept") continue;
    const double x = name[0] == 'T' ? t : name[0] == 'R' ? r : g;
    size += std::abs(v * std::pow(x, name[1] - '0'));
  }
  return size;
}

TEST(CoefficientExport, CHeadersCompileAndAgreeWithTheLibrary) {
  const std::string cc = find_c_compiler();
  if (cc.empty()) GTEST_SKIP() << "no C compiler (cc, gcc, clang, $CC) found";
  TempDir dir;
  ASSERT_FALSE(dir.path.empty());

  const DriftFit paper = pooled_fit(DriftModelForm::kPaper);
  const DriftFit centred = pooled_fit(DriftModelForm::kCentered);
  StartTemperatureOptions paper_form;  // the header without an intercept
  paper_form.form = DriftModelForm::kPaper;
  auto model = fit_start_temperature_model(start_runs(), paper_form);
  ASSERT_TRUE(model.ok()) << model.error().message;
  write_file(dir.path / "drift_paper.h", drift_fit_c_header(paper, kInfo, "fog_paper"));
  write_file(dir.path / "drift_centred.h", drift_fit_c_header(centred, kInfo, "fog-centred"));
  write_file(dir.path / "start.h", start_model_c_header(*model, kInfo));

  // Points: every 37th of the first comparison run; start temperatures
  // inside and outside the fitted range.
  const std::vector<AnalysisSeries> runs =
      load_runs(read_reference_lines("comparison_grid.txt", kScript));
  const AnalysisSeries& s = runs[1];
  const Inputs in = variables(s, paper.derivative_window_s);
  std::vector<std::size_t> idx;
  for (std::size_t i = 0; i < s.t_s.size(); i += 37) idx.push_back(i);
  const std::vector<double> t0s = {-30.0, -14.0, 0.5, 17.25, 33.0, 44.0, 70.0};

  std::string main_c =
      "#include <stdio.h>\n#include \"drift_paper.h\"\n#include \"drift_centred.h\"\n"
      "#include \"start.h\"\n\nstatic const double in[][3] = {\n";
  for (std::size_t i : idx) {
    main_c += fmt::format("  {{{:.17g}, {:.17g}, {:.17g}}},\n", in.t[i], in.r[i], in.g[i]);
  }
  main_c += "};\nstatic const double t0s[] = {";
  for (double t0 : t0s) main_c += fmt::format("{:.17g}, ", t0);
  main_c += fmt::format(
      "}};\n\nint main(void) {{\n  size_t i, k;\n"
      "  for (i = 0; i < {0}; ++i) printf(\"%.17g\\n\", fog_paper_terms(in[i][0], in[i][1], "
      "in[i][2]));\n"
      "  for (i = 0; i < {0}; ++i) printf(\"%.17g\\n\", fog_centred_terms(in[i][0], in[i][1], "
      "in[i][2]));\n"
      "  for (k = 0; k < {1}; ++k) {{\n"
      "    double a[GYROTHERM_START_N_COEFFICIENTS];\n"
      "    gyrotherm_start_coefficients(t0s[k], a);\n"
      "    for (i = 0; i < GYROTHERM_START_N_COEFFICIENTS; ++i) printf(\"%.17g\\n\", a[i]);\n"
      "    for (i = 0; i < {0}; ++i) printf(\"%.17g\\n\", gyrotherm_start_terms(t0s[k], "
      "in[i][0], in[i][1], in[i][2]));\n"
      "  }}\n"
      "  printf(\"%.17g\\n\", gyrotherm_start_T1_A[3] + fog_paper_G1 + fog_centred_intercept);\n"
      "  return 0;\n}}\n",
      idx.size(), t0s.size());
  write_file(dir.path / "main.c", main_c);
  const std::vector<double> out = compile_and_run(cc, dir.path);
  const std::size_t names = model->cubic.size();
  ASSERT_EQ(out.size(), 2 * idx.size() + t0s.size() * (names + idx.size()) + 1);

  std::size_t o = 0;
  for (const DriftFit* fit : {&paper, &centred}) {
    SCOPED_TRACE(std::string(to_string(fit->form)));
    auto terms = drift_terms(*fit, s);
    ASSERT_TRUE(terms.ok()) << terms.error().message;
    for (std::size_t i : idx) {
      const double size = term_size(fit->coefficients, in.t[i], in.r[i], in.g[i]);
      EXPECT_NEAR(out[o++], (*terms)[i], 1e-12 * size) << "point " << i;
    }
  }
  // Coefficient order in the header: the design order (T.., R.., G..).
  const std::vector<std::string> order = {"T1", "T2", "T3", "T4", "R1", "G1"};
  ASSERT_EQ(names, order.size());
  for (double t0 : t0s) {
    auto at = coefficients_at(*model, t0);
    ASSERT_TRUE(at.ok());
    for (const std::string& name : order) {
      EXPECT_EQ(out[o++], at->fit.coefficients.at(name)) << name << " at T0 " << t0;  // same Horner
    }
    AnalysisSeries copy = s;
    auto terms = drift_terms(at->fit, copy);
    ASSERT_TRUE(terms.ok());
    for (std::size_t i : idx) {
      const double size = term_size(at->fit.coefficients, in.t[i], in.r[i], in.g[i]);
      EXPECT_NEAR(out[o++], (*terms)[i], 1e-12 * size) << "point " << i << " T0 " << t0;
    }
  }
  EXPECT_EQ(out[o], model->cubic.at("T1")[3] + paper.coefficients.at("G1") +
                        centred.coefficients.at("intercept"));
}

TEST(CoefficientExport, HeaderNamesAreCIdentifiers) {
  const DriftFit fit = pooled_fit(DriftModelForm::kPaper);
  const std::string h = drift_fit_c_header(fit, kInfo, "3-axis fog");
  EXPECT_NE(h.find("#ifndef _3_AXIS_FOG_DRIFT_FIT_PAPER_H_"), std::string::npos) << h;
  EXPECT_NE(h.find("static const double _3_axis_fog_T4 = "), std::string::npos) << h;
  EXPECT_NE(h.find("static inline double _3_axis_fog_terms("), std::string::npos) << h;
  EXPECT_NE(h.find("FOG-0042"), std::string::npos);
  EXPECT_NE(h.find("12, 13, 15"), std::string::npos);
}

}  // namespace
}  // namespace gyrotherm::analysis
