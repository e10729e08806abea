// The coefficient names and units the docs give against the code (issue 15,
// item 6): a wrong unit in the docs makes wrong coefficients on the gyro's
// computer (°C/min where the code uses °C/s is a factor of 60).
//
// Every docs/*.md and README.md is read:
// - a table row "| `T2` | unit |" must give analysis::coefficient_unit's unit;
//   docs/analysis.md must list every coefficient a fit can produce;
// - a family range "`R1`…`R4` (°/h per (°C/s)ʲ)" must name the unit of its
//   first member (the power letter left out);
// - "per °C/min" appears nowhere (no coefficient is per °C/min);
// - every ```json example with "coefficients" (a FIT) parses, each key of its
//   coefficients / standard_errors is one coefficient_names gives for its
//   model and form, and its top-level and "inputs" keys are ones the
//   daemon's stored fit (station::to_json(fit_record(...))) has.
#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <regex>
#include <set>
#include <sstream>
#include <string>
#include <vector>

#include "gyrotherm/analysis/drift_model.h"
#include "gyrotherm/calibration/run_analysis.h"
#include "gyrotherm/station/control.h"

namespace gyrotherm::calibration {
namespace {

namespace fs = std::filesystem;
using nlohmann::json;

struct Doc {
  std::string name;  // relative to the source tree
  std::vector<std::string> lines;
};

std::vector<Doc> docs() {
  std::vector<Doc> out;
  const fs::path root = GYROTHERM_SOURCE_DIR;
  std::vector<fs::path> files = {root / "README.md"};
  for (const auto& e : fs::directory_iterator(root / "docs")) {
    if (e.path().extension() == ".md") files.push_back(e.path());
  }
  for (const auto& f : files) {
    std::ifstream in(f);
    EXPECT_TRUE(in) << f;
    Doc d{fs::relative(f, root).string(), {}};
    for (std::string line; std::getline(in, line);) d.lines.push_back(line);
    out.push_back(std::move(d));
  }
  return out;
}

std::vector<std::string> all_names() {
  return analysis::coefficient_names({.t_order = 4, .r_order = 4, .g_order = 4},
                                     analysis::DriftModelForm::kCentered);
}

std::string trim(std::string s) {
  const auto b = s.find_first_not_of(' ');
  const auto e = s.find_last_not_of(' ');
  return b == std::string::npos ? "" : s.substr(b, e - b + 1);
}

TEST(DocsUnits, TableRowsGiveTheCodesUnits) {
  const std::regex row(R"(^\|\s*`(intercept|[TRG][1-4])`\s*\|([^|]*)\|)");
  std::set<std::string> in_analysis_md;
  int rows = 0;
  for (const Doc& d : docs()) {
    for (std::size_t i = 0; i < d.lines.size(); ++i) {
      std::smatch m;
      if (!std::regex_search(d.lines[i], m, row)) continue;
      ++rows;
      const std::string name = m[1];
      EXPECT_EQ(trim(m[2]), analysis::coefficient_unit(name))
          << d.name << ":" << i + 1 << ": unit of " << name;
      if (d.name == "docs/analysis.md") in_analysis_md.insert(name);
    }
  }
  EXPECT_GT(rows, 0) << "no coefficient table found";
  for (const auto& n : all_names()) {
    EXPECT_TRUE(in_analysis_md.count(n)) << "docs/analysis.md does not list " << n;
  }
}

TEST(DocsUnits, FamilyRangesGiveTheCodesUnits) {
  // "`T1`…`T4` (°/h per °Cⁱ" or "`R1`…`R4` °/h per (°C/s)^j": the unit
  // after "per", up to a power letter, ')' followed by a space/comma, or ','.
  const std::regex range(R"(`([TRG])1`\s*(?:…|\.\.\.)\s*`[TRG]4`[^°]{0,20}°/h per ([^,;]*))");
  int found = 0;
  for (const Doc& d : docs()) {
    // Paragraphs: a statement may wrap onto the next line.
    std::vector<std::string> paragraphs(d.lines.size());
    for (std::size_t i = 0; i < d.lines.size(); ++i) {
      for (std::size_t k = i; k < d.lines.size() && !d.lines[k].empty(); ++k) {
        paragraphs[i] += d.lines[k] + " ";
        if (k > i + 4) break;  // a few lines on are enough
      }
    }
    for (std::size_t i = 0; i < d.lines.size(); ++i) {
      const std::string& text = paragraphs[i];
      for (std::sregex_iterator it(text.begin(), text.end(), range), end; it != end; ++it) {
        // Each statement is checked from the line it starts on.
        if (static_cast<std::size_t>(it->position(0)) >= d.lines[i].size()) break;
        ++found;
        const std::string family = (*it)[1];
        std::string unit = (*it)[2];
        // Cut at the power: a superscript letter, "^", or the closing
        // parenthesis of the whole statement.
        for (const char* stop : {"ⁱ", "ʲ", "ᵏ", "^"}) {
          if (auto p = unit.find(stop); p != std::string::npos) unit = unit.substr(0, p);
        }
        if (unit.rfind("(", 0) == 0) {
          unit = unit.substr(1, unit.find(')') - 1);  // "(°C/s)ʲ" -> "°C/s"
        } else if (auto p = unit.find(')'); p != std::string::npos) {
          unit = unit.substr(0, p);  // "°Cⁱ)" was cut above; "°C)" -> "°C"
        }
        unit = trim(unit);
        if (auto p = unit.find(' '); p != std::string::npos) unit = unit.substr(0, p);
        EXPECT_EQ("°/h per " + unit, analysis::coefficient_unit(family + "1"))
            << d.name << ":" << i + 1 << ": " << d.lines[i];
      }
    }
  }
  EXPECT_GT(found, 0) << "no `X1`…`X4` unit statement found";
}

TEST(DocsUnits, NoCoefficientIsPerDegreePerMinute) {
  for (const Doc& d : docs()) {
    for (std::size_t i = 0; i < d.lines.size(); ++i) {
      EXPECT_EQ(d.lines[i].find("per °C/min"), std::string::npos)
          << d.name << ":" << i + 1 << ": " << d.lines[i];
      EXPECT_EQ(d.lines[i].find("per (°C/min)"), std::string::npos)
          << d.name << ":" << i + 1 << ": " << d.lines[i];
    }
  }
}

TEST(DocsUnits, FitExamplesUseKeysAFitProduces) {
  // What the daemon stores and serves for a fit.
  auto fit = analysis::DriftFit{};
  fit.spec = {.t_order = 1};
  const json produced = station::to_json(fit_record(fit, {1}, {}, 1.0));
  int examples = 0;
  for (const Doc& d : docs()) {
    for (std::size_t i = 0; i < d.lines.size(); ++i) {
      if (d.lines[i] != "```json") continue;
      std::string text;
      const std::size_t start = i + 1;
      for (++i; i < d.lines.size() && d.lines[i] != "```"; ++i) text += d.lines[i] + "\n";
      if (text.find("\"coefficients\"") == std::string::npos) continue;
      ++examples;
      const std::string where = d.name + ":" + std::to_string(start);
      const json j = json::parse(text, nullptr, false);
      ASSERT_FALSE(j.is_discarded()) << where << ": the example is not JSON";
      for (const auto& [key, value] : j.items()) {
        EXPECT_TRUE(produced.contains(key)) << where << ": a fit has no key \"" << key << "\"";
      }
      if (j.contains("inputs")) {
        for (const auto& [key, value] : j["inputs"].items()) {
          EXPECT_TRUE(produced["inputs"].contains(key))
              << where << ": a fit's inputs have no key \"" << key << "\"";
        }
      }
      auto spec = analysis::parse_model_spec(j.value("model", ""));
      ASSERT_TRUE(spec.ok()) << where << ": model: " << spec.error().message;
      auto form = analysis::parse_drift_model_form(j.value("form", ""));
      ASSERT_TRUE(form.ok()) << where << ": form: " << form.error().message;
      const auto names = analysis::coefficient_names(*spec, *form);
      for (const char* field : {"coefficients", "standard_errors"}) {
        if (!j.contains(field)) continue;
        for (const auto& [key, value] : j[field].items()) {
          EXPECT_NE(std::find(names.begin(), names.end(), key), names.end())
              << where << ": " << field << " key \"" << key << "\" is not a coefficient of "
              << j["model"] << " (" << j["form"] << " form)";
        }
      }
    }
  }
  EXPECT_GT(examples, 0) << "no documented fit example found";
}

}  // namespace
}  // namespace gyrotherm::calibration
