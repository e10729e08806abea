// The configuration stored with each run (runs.config_json): the config in
// force as JSON, laid out like the TOML file, tokens redacted; and how the
// CLI and reports read it back (JSON, or the TOML text of runs stored before
// schema v6).
#include "gyrotherm/config/run_config.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>
#include <toml++/toml.h>

#include <nlohmann/json.hpp>
#include <string>

#include "gyrotherm/calibration/run_analysis.h"
#include "gyrotherm/config/config.h"

namespace gyrotherm::config {
namespace {

using json = nlohmann::json;
using ::testing::HasSubstr;
using ::testing::Not;

// Every key the TOML file sets is in the JSON with the value in force.
void expect_same(const toml::table& file, const json& stored, const std::string& where) {
  for (const auto& [key_node, value] : file) {
    const std::string key(key_node.str());
    const std::string at = where.empty() ? key : where + "." + key;
    if (at == "simulator" && stored.contains("simulator")) {
      // gyrotherm-sim's section: the daemon keeps only endpoints_file.
      continue;
    }
    // [[dut]] is stored as "duts" (one object per DUT, every key resolved;
    // checked against the file in DutConfig tests).
    if (at == "dut" && stored.contains("duts")) {
      EXPECT_EQ(stored["duts"].size(), value.as_array() ? value.as_array()->size() : 0u) << at;
      continue;
    }
    ASSERT_TRUE(stored.is_object() && stored.contains(key)) << at << " missing in " << stored;
    const json& j = stored[key];
    if (const auto* t = value.as_table()) {
      expect_same(*t, j, at);
    } else if (const auto* a = value.as_array()) {
      ASSERT_TRUE(j.is_array()) << at;
      EXPECT_EQ(j.size(), a->size()) << at;
    } else if (auto s = value.value<std::string>(); s && value.is_string()) {
      EXPECT_EQ(j, *s) << at;
    } else if (value.is_boolean()) {
      EXPECT_EQ(j, *value.value<bool>()) << at;
    } else if (auto d = value.value<double>()) {
      ASSERT_TRUE(j.is_number()) << at << ": " << j;
      EXPECT_DOUBLE_EQ(j.get<double>(), *d) << at;
    }
  }
}

TEST(RunConfig, StoredJsonMirrorsTheLoadedConfigFiles) {
  for (const char* name : {"station.toml", "demo.toml"}) {
    const std::string path = std::string(GYROTHERM_SOURCE_DIR) + "/config/" + name;
    auto cfg = load_station_config(path);
    ASSERT_TRUE(cfg.ok()) << cfg.error().message;
    const json stored = run_config_json(*cfg);
    SCOPED_TRACE(name);
    expect_same(toml::parse_file(path), stored, "");
    // Defaults the file leaves out are stored too.
    EXPECT_EQ(stored["api"]["max_connections"], 64);
    EXPECT_EQ(json::parse(stored.dump()), stored) << "round trip";
  }
}

TEST(RunConfig, StoredJsonHoldsNoToken) {
  auto cfg = parse_station_config(R"(
[station]
name = "lab-3"
latitude_deg = 31.9
[chamber]
port = 1502
[probes]
port = 1502
[gyro]
device = "/dev/ttyUSB0"
[api]
tokens = ["control-token-0123456789"]
read_tokens = ["read-token-0123456789ab"]
[analysis]
ma_window = 51
model = "T2"
allan_taus = "decade"
)",
                                  "t.toml");
  ASSERT_TRUE(cfg.ok()) << cfg.error().message;
  const std::string text = run_config_json(*cfg).dump();
  EXPECT_THAT(text, Not(HasSubstr("control-token")));
  EXPECT_THAT(text, Not(HasSubstr("read-token")));
  EXPECT_THAT(text, HasSubstr(R"("tokens":["<redacted>"])"));

  // The CLI and the reports read it back.
  storage::RunRecord run;
  run.config_json = text;
  const RunConfig back = calibration::read_run_config(run);
  EXPECT_EQ(back.station_name, "lab-3");
  EXPECT_EQ(back.ma_window, 51);
  EXPECT_EQ(back.model, "T2");
  EXPECT_EQ(back.allan_taus, "decade");
  EXPECT_EQ(back.bin_s, 1.0);
  EXPECT_EQ(back.l0_window_s, 120.0);
}

// Runs stored before schema v6 kept the config file's TOML text: still read.
TEST(RunConfig, TomlOfOlderRunsIsStillRead) {
  storage::RunRecord run;
  run.config_toml = "[station]\nname = \"lab-1\"\n[analysis]\nma_window = 31\nbin_s = 2.0\n";
  RunConfig c = calibration::read_run_config(run);
  EXPECT_EQ(c.station_name, "lab-1");
  EXPECT_EQ(c.ma_window, 31);
  EXPECT_EQ(c.bin_s, 2.0);
  auto settings = calibration::analysis_settings_of_run(run);
  ASSERT_TRUE(settings.ok()) << settings.error().message;
  EXPECT_EQ(settings->table1.ma_window, 31u);
  // A run with JSON reads the JSON.
  run.config_json = R"({"analysis":{"ma_window":41}})";
  EXPECT_EQ(calibration::read_run_config(run).ma_window, 41);
}

}  // namespace
}  // namespace gyrotherm::config
