#include "gyrotherm/config/config.h"

#include <fmt/format.h>
#include <gmock/gmock.h>
#include <gtest/gtest.h>
#include <toml++/toml.h>
#include <unistd.h>

#include <algorithm>
#include <cstring>
#include <filesystem>
#include <fstream>

#include "gyrotherm/calibration/run_analysis.h"
#include "gyrotherm/config/run_config.h"
#include "gyrotherm/config/sim_endpoints.h"

namespace gyrotherm::config {
namespace {

using ::testing::AllOf;
using ::testing::HasSubstr;
using ::testing::Not;

constexpr const char* kMinimal = R"(
[station]
latitude_deg = 31.9
[chamber]
port = 1502
[probes]
port = 1502
[gyro]
device = "/dev/ttyUSB0"
)";

TEST(Config, ShippedConfigsLoad) {
  for (const char* name : {"demo.toml", "station.toml"}) {
    auto cfg = load_station_config(std::string(GYROTHERM_SOURCE_DIR) + "/config/" + name);
    ASSERT_TRUE(cfg.ok()) << name << ":\n" << cfg.error().message;
  }
}

TEST(Config, DemoConfigValues) {
  auto cfg = load_station_config(std::string(GYROTHERM_SOURCE_DIR) + "/config/demo.toml");
  ASSERT_TRUE(cfg.ok()) << cfg.error().message;
  EXPECT_DOUBLE_EQ(cfg->station.latitude_deg, 31.9);
  EXPECT_EQ(cfg->chamber.map.setpoint.address, 2782);
  EXPECT_EQ(cfg->chamber.map.process_value.address, 2820);
  EXPECT_EQ(cfg->probes.endpoint.unit_id, 2);
  EXPECT_EQ(cfg->simulator.endpoints_file, "demo/sim-endpoints.toml");
  ASSERT_TRUE(cfg->simulator_table.has_value());
  EXPECT_TRUE(cfg->simulator_table->contains("thermal"));
}

TEST(Config, DefaultsFromTheBrief) {
  auto cfg = parse_station_config(kMinimal, "min.toml");
  ASSERT_TRUE(cfg.ok()) << cfg.error().message;
  EXPECT_DOUBLE_EQ(cfg->station.min_temp_c, -20.0);
  EXPECT_DOUBLE_EQ(cfg->station.max_temp_c, 60.0);
  EXPECT_DOUBLE_EQ(cfg->station.safe_setpoint_c, 23.0);
  EXPECT_EQ(cfg->chamber.profile, "watlow-f4t");
  EXPECT_EQ(cfg->api.bind, "127.0.0.1");
  EXPECT_EQ(cfg->analysis.ma_window, 101);
  EXPECT_DOUBLE_EQ(cfg->analysis.l0_window_s, 120.0);
  EXPECT_EQ(cfg->gyro.protocol, "kvh1750");
}

// The limits schedules are checked against come from [station].
TEST(Config, StationLimitsComeFromTheStationSection) {
  auto cfg = parse_station_config(kMinimal, "min.toml");
  ASSERT_TRUE(cfg.ok()) << cfg.error().message;
  auto limits = station_limits(*cfg);
  EXPECT_DOUBLE_EQ(limits.min_temp_c, -20.0);
  EXPECT_DOUBLE_EQ(limits.max_temp_c, 60.0);
  EXPECT_DOUBLE_EQ(limits.max_ramp_c_per_min, 2.0);
  std::string text = kMinimal;
  text.insert(text.find("[chamber]"),
              "min_temp_c = -40.0\nmax_temp_c = 85.0\nmax_ramp_c_per_min = 0.5\n");
  cfg = parse_station_config(text, "wide.toml");
  ASSERT_TRUE(cfg.ok()) << cfg.error().message;
  limits = station_limits(*cfg);
  EXPECT_DOUBLE_EQ(limits.min_temp_c, -40.0);
  EXPECT_DOUBLE_EQ(limits.max_temp_c, 85.0);
  EXPECT_DOUBLE_EQ(limits.max_ramp_c_per_min, 0.5);
}

// [analysis] compare_smooth_points: the Tables II-IV moving average (odd;
// 1 = raw), into the daemon's analysis settings.
TEST(Config, CompareSmoothPoints) {
  auto cfg = parse_station_config(kMinimal, "min.toml");
  ASSERT_TRUE(cfg.ok()) << cfg.error().message;
  EXPECT_EQ(cfg->analysis.compare_smooth_points, 101);
  EXPECT_EQ(calibration::analysis_settings(*cfg).compare_smooth_points, 101u);
  cfg = parse_station_config(std::string(kMinimal) + "[analysis]\ncompare_smooth_points = 1\n",
                             "raw.toml");
  ASSERT_TRUE(cfg.ok()) << cfg.error().message;
  EXPECT_EQ(calibration::analysis_settings(*cfg).compare_smooth_points, 1u);
  cfg = parse_station_config(std::string(kMinimal) + "[analysis]\ncompare_smooth_points = 100\n",
                             "even.toml");
  ASSERT_FALSE(cfg.ok());
  EXPECT_THAT(cfg.error().message, HasSubstr("even.toml:11: analysis.compare_smooth_points"));
  EXPECT_EQ(read_run_config("[analysis]\ncompare_smooth_points = 51\n").compare_smooth_points, 51);
}

TEST(Config, ExplicitRegisterMap) {
  auto cfg = parse_station_config(R"(
[station]
[chamber]
registers.setpoint = { address = 10, type = "int16", scale = 0.1 }
registers.process_value = { address = 11, function = "input", type = "float32", word_order = "high-first" }
[probes]
[gyro]
device = "/dev/ttyS0"
)",
                                  "custom.toml");
  ASSERT_TRUE(cfg.ok()) << cfg.error().message;
  EXPECT_EQ(cfg->chamber.profile, "custom");
  EXPECT_EQ(cfg->chamber.map.setpoint.address, 10);
  EXPECT_EQ(cfg->chamber.map.setpoint.type, drivers::RegisterType::kInt16);
  EXPECT_DOUBLE_EQ(cfg->chamber.map.setpoint.scale, 0.1);
  EXPECT_EQ(cfg->chamber.map.process_value.function, drivers::RegisterFunction::kInput);
  EXPECT_EQ(cfg->chamber.map.process_value.word_order, drivers::WordOrder::kHighFirst);
}

TEST(Config, BadRegisterMapNamesEveryField) {
  auto cfg = parse_station_config(R"([station]
[chamber]
registers.setpoint = { address = 70000, type = "int8", word_order = "middle", scale = 0 }
[probes]
[gyro]
device = "/dev/ttyS0"
)",
                                  "regs.toml");
  ASSERT_FALSE(cfg.ok());
  const std::string& m = cfg.error().message;
  EXPECT_THAT(m, HasSubstr("regs.toml:3: chamber.registers.setpoint.address: 70000 is not a "
                           "register address"));
  EXPECT_THAT(m, HasSubstr("chamber.registers.setpoint.type:"));
  EXPECT_THAT(m, HasSubstr("int8"));
  EXPECT_THAT(m, HasSubstr("chamber.registers.setpoint.word_order:"));
  EXPECT_THAT(m, HasSubstr("chamber.registers.setpoint.scale: must not be 0"));
  EXPECT_THAT(m, HasSubstr("chamber.registers.process_value: missing"));
}

TEST(Config, F4tAlarmDefaultsToAlarmOneWithWatlowsStates) {
  auto cfg = parse_station_config(R"([station]
[chamber]
profile = "watlow-f4t"
[chamber.alarm]
[probes]
[gyro]
device = "/dev/ttyS0"
)",
                                  "alarm.toml");
  ASSERT_TRUE(cfg.ok()) << cfg.error().message;
  ASSERT_TRUE(cfg->chamber.map.alarm);
  const auto& alarm = *cfg->chamber.map.alarm;
  EXPECT_EQ(alarm.reg.address, 1356);
  EXPECT_EQ(alarm.reg.type, drivers::RegisterType::kUint16);
  EXPECT_FALSE(alarm.is_alarm(61));  // None: the value an F4T reads with no alarm
  EXPECT_TRUE(alarm.is_alarm(7));
  ASSERT_TRUE(cfg->chamber.map.units);
  EXPECT_EQ(cfg->chamber.map.units->reg.address, 6730);
  EXPECT_TRUE(cfg->chamber.map.process_value.read_only);
}

TEST(Config, AlarmValuesAreNamedByTheConfig) {
  auto cfg = parse_station_config(R"([station]
[chamber]
profile = "watlow-f4"
[chamber.alarm]
address = 200
alarm_values = [1, 2]
[probes]
[gyro]
device = "/dev/ttyS0"
)",
                                  "alarm.toml");
  ASSERT_TRUE(cfg.ok()) << cfg.error().message;
  ASSERT_TRUE(cfg->chamber.map.alarm);
  EXPECT_EQ(cfg->chamber.map.alarm->reg.address, 200);
  EXPECT_FALSE(cfg->chamber.map.alarm->is_alarm(0));
  EXPECT_TRUE(cfg->chamber.map.alarm->is_alarm(2));
  EXPECT_FALSE(cfg->chamber.map.alarm->is_alarm(3));

  auto ok = parse_station_config(R"([station]
[chamber]
[chamber.alarm]
address = 1456
ok_values = [61, 88, 12, 5]
[probes]
[gyro]
device = "/dev/ttyS0"
)",
                                 "alarm.toml");
  ASSERT_TRUE(ok.ok()) << ok.error().message;
  EXPECT_EQ(ok->chamber.map.alarm->reg.address, 1456);
  EXPECT_FALSE(ok->chamber.map.alarm->is_alarm(5));
  EXPECT_TRUE(ok->chamber.map.alarm->is_alarm(7));

  auto bad = parse_station_config(R"([station]
[chamber]
profile = "generic"
[chamber.alarm]
ok_values = [0]
alarm_values = ["x"]
[probes]
[gyro]
device = "/dev/ttyS0"
)",
                                  "alarm.toml");
  ASSERT_FALSE(bad.ok());
  EXPECT_THAT(bad.error().message, HasSubstr("chamber.alarm.address: missing"));
  EXPECT_THAT(bad.error().message,
              HasSubstr("chamber.alarm.alarm_values: give either ok_values or alarm_values"));

  auto empty = parse_station_config(R"([station]
[chamber]
[chamber.alarm]
alarm_values = []
[probes]
[gyro]
device = "/dev/ttyS0"
)",
                                    "alarm.toml");
  ASSERT_FALSE(empty.ok());
  EXPECT_THAT(empty.error().message,
              HasSubstr("alarm.toml:4: chamber.alarm.alarm_values: must list at least one value"));
}

TEST(Config, EveryErrorNamesFileLineAndKey) {
  auto cfg = parse_station_config(R"([station]
latitude_deg = 120
orientaton = "up"
[chamber]
port = "five"
profile = "watlow-f9"
[probes]
[gyro]
device = "/dev/ttyUSB0"
unit = "grad"
[storage]
commit_interval_s = 5
)",
                                  "bad.toml");
  ASSERT_FALSE(cfg.ok());
  const std::string& m = cfg.error().message;
  EXPECT_THAT(m, HasSubstr("bad.toml:2: station.latitude_deg: 120 is out of range"));
  EXPECT_THAT(m, HasSubstr("bad.toml:3: station.orientaton: unknown key"));
  EXPECT_THAT(m, HasSubstr("bad.toml:5: chamber.port: expected an integer, got string"));
  EXPECT_THAT(m, HasSubstr("bad.toml:6: chamber.profile:"));
  EXPECT_THAT(m, HasSubstr("watlow-f9"));
  EXPECT_THAT(m, HasSubstr("bad.toml:10: gyro.unit: \"grad\" is not one of: rad, deg"));
  EXPECT_THAT(m, HasSubstr("bad.toml:12: storage.commit_interval_s: 5 is out of range"));
}

// Issue 15 item 18: a host that cannot be an address is refused at load,
// naming file, line and key; names and IP literals are accepted (names are
// resolved at connect).
TEST(Config, ModbusHostIsANameOrAnAddress) {
  auto with_host = [](const std::string& host) {
    return parse_station_config(fmt::format(R"([station]
latitude_deg = 31.9
[chamber]
host = "{}"
port = 1502
[probes]
port = 1502
[gyro]
device = "/dev/ttyUSB0"
)",
                                            host),
                                "hosts.toml");
  };
  for (const char* good : {"127.0.0.1", "localhost", "chamber-3.lab.example.org", "::1", "fe80::1",
                           "chamber.invalid"}) {
    auto cfg = with_host(good);
    ASSERT_TRUE(cfg.ok()) << good << ": " << cfg.error().message;
    EXPECT_EQ(cfg->chamber.endpoint.host, good);
  }
  for (const char* bad : {"300.1.2.3", "1.2.3", "10.0.0.256", "chamber_3.lab", "-chamber", "a..b",
                          "::g", "", "chamber 3"}) {
    auto cfg = with_host(bad);
    ASSERT_FALSE(cfg.ok()) << "accepted host \"" << bad << "\"";
    EXPECT_THAT(cfg.error().message, HasSubstr("hosts.toml:4: chamber.host: ")) << bad;
  }
  EXPECT_THAT(with_host("300.1.2.3").error().message,
              HasSubstr("\"300.1.2.3\" is not a valid IPv4 address"));
}

TEST(Config, MissingSectionsAndSyntaxErrors) {
  auto cfg = parse_station_config("[station]\n", "a.toml");
  ASSERT_FALSE(cfg.ok());
  EXPECT_THAT(cfg.error().message, HasSubstr("chamber: missing section"));
  // Neither [[dut]] nor the older [gyro]: no device under test.
  EXPECT_THAT(cfg.error().message, HasSubstr("a.toml: dut: missing: give each device under test"));
  auto syntax = parse_station_config("[station\nname = 1\n", "b.toml");
  ASSERT_FALSE(syntax.ok());
  EXPECT_THAT(syntax.error().message, HasSubstr("b.toml:1: TOML syntax error"));
  auto nofile = load_station_config("/nonexistent/station.toml");
  ASSERT_FALSE(nofile.ok());
  EXPECT_THAT(nofile.error().message, HasSubstr("/nonexistent/station.toml: cannot open file"));
}

// [storage] db in a directory that does not exist: an error naming the
// file, the line, the key and the directory (SQLite would not create it;
// the daemon would have started an empty station in a new one).
TEST(Config, DatabaseDirectoryMustExist) {
  const std::filesystem::path dir =
      std::filesystem::temp_directory_path() / ("gyrotherm-dbdir-" + std::to_string(::getpid()));
  std::filesystem::remove_all(dir);
  std::filesystem::create_directories(dir);
  const auto with_db = [&](const std::string& db) {
    const std::string text = std::string(kMinimal) + "[storage]\ndb = \"" + db + "\"\n";
    auto cfg = parse_station_config(text, "station.toml");
    EXPECT_TRUE(cfg.ok()) << cfg.error().message;  // parsing itself does not look at the disk
    return *cfg;
  };
  const int db_line =
      static_cast<int>(std::count(kMinimal, kMinimal + std::strlen(kMinimal), '\n')) + 2;

  const StationConfig missing = with_db((dir / "nope" / "station.db").string());
  EXPECT_EQ(missing.storage.db_line, db_line);
  const Status st = check_database_directory(missing);
  ASSERT_FALSE(st.ok());
  EXPECT_THAT(st.error().message,
              HasSubstr(fmt::format("station.toml:{}: storage.db: the database's directory {} "
                                    "does not exist",
                                    db_line, (dir / "nope").string())));
  const Status by_option = check_database_directory(missing, "--db");
  ASSERT_FALSE(by_option.ok());
  EXPECT_THAT(by_option.error().message, HasSubstr("--db: the database's directory"));

  { std::ofstream((dir / "file").string()) << "x"; }
  const Status not_dir = check_database_directory(with_db((dir / "file" / "station.db").string()));
  ASSERT_FALSE(not_dir.ok());
  EXPECT_THAT(not_dir.error().message, HasSubstr("is not a directory"));

  const Status relative = check_database_directory(with_db("no-such-dir-here/station.db"));
  ASSERT_FALSE(relative.ok());
  EXPECT_THAT(relative.error().message, HasSubstr("a relative path starts from the working"));

  for (const std::string& ok : {(dir / "station.db").string(), std::string("station.db"),
                                std::string(":memory:"), std::string(""), std::string("./x.db")}) {
    const Status s = check_database_directory(with_db(ok));
    EXPECT_TRUE(s.ok()) << ok << ": " << s.error().message;
  }
  EXPECT_TRUE(check_database_directory(*parse_station_config(kMinimal, "d.toml")).ok())
      << "the default, in the working directory";
  std::filesystem::remove_all(dir);
}

TEST(Config, ShortTokensAreRefused) {
  auto cfg = parse_station_config(std::string(kMinimal) + "[api]\ntokens = [\"abc\"]\n", "t.toml");
  ASSERT_FALSE(cfg.ok());
  EXPECT_THAT(cfg.error().message,
              HasSubstr("api.tokens: each token must be a string of at least 16"));
  EXPECT_THAT(cfg.error().message, Not(HasSubstr("abc"))) << "tokens never appear in messages";
}

TEST(Config, ApiLimitsAreReadWithDefaultsAndRangeChecked) {
  auto defaults = parse_station_config(std::string(kMinimal), "t.toml");
  ASSERT_TRUE(defaults.ok()) << defaults.error().message;
  EXPECT_EQ(defaults->api.read_timeout_s, 10.0);
  EXPECT_EQ(defaults->api.max_connections, 64);
  EXPECT_EQ(defaults->api.max_header_bytes, 8192);
  EXPECT_EQ(defaults->api.max_body_bytes, 65536);
  EXPECT_EQ(defaults->api.max_stream_clients, 32);
  EXPECT_EQ(defaults->api.stream_queue_bytes, 262144);
  EXPECT_EQ(defaults->api.web_root, "");

  auto set = parse_station_config(std::string(kMinimal) +
                                      "[api]\nread_timeout_s = 2.5\nmax_connections = 8\n"
                                      "max_header_bytes = 4096\nmax_body_bytes = 2048\n"
                                      "max_stream_clients = 3\nstream_queue_bytes = 65536\n"
                                      "web_root = \"/srv/web\"\n",
                                  "t.toml");
  ASSERT_TRUE(set.ok()) << set.error().message;
  EXPECT_EQ(set->api.read_timeout_s, 2.5);
  EXPECT_EQ(set->api.max_connections, 8);
  EXPECT_EQ(set->api.max_header_bytes, 4096);
  EXPECT_EQ(set->api.max_body_bytes, 2048);
  EXPECT_EQ(set->api.max_stream_clients, 3);
  EXPECT_EQ(set->api.stream_queue_bytes, 65536);
  EXPECT_EQ(set->api.web_root, "/srv/web");

  auto bad = parse_station_config(std::string(kMinimal) +
                                      "[api]\nmax_connections = 1\nmax_body_bytes = 1.5\n"
                                      "read_timeout_s = 0\n",
                                  "t.toml");
  ASSERT_FALSE(bad.ok());
  EXPECT_THAT(bad.error().message, HasSubstr("api.max_connections: 1 is out of range"));
  EXPECT_THAT(bad.error().message, HasSubstr("api.max_body_bytes"));
  EXPECT_THAT(bad.error().message, HasSubstr("api.read_timeout_s: 0 is out of range"));
}

TEST(Config, ApiAccessDefaults) {
  // An [api] section without bind: loopback only, reads open, 10 failures.
  auto cfg = parse_station_config(std::string(kMinimal) + "[api]\nport = 8751\n", "t.toml");
  ASSERT_TRUE(cfg.ok()) << cfg.error().message;
  EXPECT_EQ(cfg->api.bind, "127.0.0.1");
  EXPECT_EQ(cfg->api.read_access, "open");
  EXPECT_TRUE(cfg->api.tokens.empty());
  EXPECT_TRUE(cfg->api.read_tokens.empty());
  EXPECT_EQ(cfg->api.max_auth_failures, 10);
}

TEST(Config, ReadTokensReadAccessAndAuthFailures) {
  auto cfg = parse_station_config(std::string(kMinimal) +
                                      "[api]\ntokens = [\"control-token-0123456789\"]\n"
                                      "read_tokens = [\"read-token-0123456789ab\", "
                                      "\"read-token-abcdefghijkl\"]\n"
                                      "read_access = \"token\"\nmax_auth_failures = 3\n",
                                  "t.toml");
  ASSERT_TRUE(cfg.ok()) << cfg.error().message;
  EXPECT_EQ(cfg->api.tokens, std::vector<std::string>{"control-token-0123456789"});
  EXPECT_EQ(cfg->api.read_tokens,
            (std::vector<std::string>{"read-token-0123456789ab", "read-token-abcdefghijkl"}));
  EXPECT_EQ(cfg->api.read_access, "token");
  EXPECT_EQ(cfg->api.max_auth_failures, 3);

  // Read tokens alone are enough for token mode (a read-only station).
  auto read_only = parse_station_config(std::string(kMinimal) +
                                            "[api]\nread_tokens = [\"read-token-0123456789ab\"]\n"
                                            "read_access = \"token\"\n",
                                        "t.toml");
  ASSERT_TRUE(read_only.ok()) << read_only.error().message;

  auto bad = parse_station_config(std::string(kMinimal) +
                                      "[api]\nread_access = \"closed\"\nmax_auth_failures = 0\n"
                                      "read_tokens = [\"short\"]\n",
                                  "t.toml");
  ASSERT_FALSE(bad.ok());
  EXPECT_THAT(bad.error().message, HasSubstr("t.toml:11: api.read_access"));
  EXPECT_THAT(bad.error().message, HasSubstr("api.max_auth_failures: 0 is out of range"));
  EXPECT_THAT(bad.error().message,
              HasSubstr("t.toml:13: api.read_tokens: each token must be a string of at least 16"));
  EXPECT_THAT(bad.error().message, Not(HasSubstr("short")));

  auto nobody =
      parse_station_config(std::string(kMinimal) + "[api]\nread_access = \"token\"\n", "t.toml");
  ASSERT_FALSE(nobody.ok());
  EXPECT_THAT(nobody.error().message, HasSubstr("api.read_access: \"token\" needs at least one"));
}

// A token has one role: listed in both arrays, or twice, it is an error that
// names the key and the line of the entry, and never quotes the token.
TEST(Config, ATokenInBothListsOrTwiceIsRefusedWithoutQuotingIt) {
  auto cfg = parse_station_config(std::string(kMinimal) + R"([api]
tokens = [
  "control-token-0123456789",
  "second-token-abcdefghij",
  "control-token-0123456789",
]
read_tokens = [
  "read-token-0123456789ab",
  "second-token-abcdefghij",
]
)",
                                  "t.toml");
  ASSERT_FALSE(cfg.ok());
  const std::string& m = cfg.error().message;
  EXPECT_THAT(m, HasSubstr("t.toml:14: api.tokens: entry 3 repeats an earlier entry")) << m;
  EXPECT_THAT(m, HasSubstr("t.toml:18: api.read_tokens: entry 2 is also in [api] tokens")) << m;
  for (const char* token :
       {"control-token", "second-token", "read-token", "0123456789", "abcdefghij"}) {
    EXPECT_THAT(m, Not(HasSubstr(token))) << "tokens never appear in messages";
  }
}

TEST(Config, ExposureWarningForOpenReadsBeyondLoopback) {
  ApiSection api;
  EXPECT_FALSE(api_exposure_warning(api)) << "127.0.0.1 (the default)";
  api.bind = "::1";
  EXPECT_FALSE(api_exposure_warning(api));
  api.bind = "0.0.0.0";
  api.tokens = {"control-token-0123456789"};
  const auto warning = api_exposure_warning(api);
  ASSERT_TRUE(warning);
  EXPECT_THAT(*warning, HasSubstr("[api] bind = \"0.0.0.0\" is not a loopback address"));
  EXPECT_THAT(*warning, Not(HasSubstr("control-token")));
  api.bind = "192.168.1.20";
  api.read_access = "token";
  EXPECT_FALSE(api_exposure_warning(api)) << "reads need a token";
}

// What a run stores of the station config (runs.config_json) holds no token.
TEST(Config, RedactedConfigTextHoldsNoToken) {
  const std::string text = std::string(kMinimal) + R"([api]
# the old token was "control-token-0123456789"
tokens = [
  "control-token-0123456789",  # the lab PC
]
read_tokens = ["read-token-0123456789ab"]
[analysis]
model = "T2"
)";
  const std::string redacted = redact_config_secrets(text);
  EXPECT_THAT(redacted, Not(HasSubstr("control-token")));
  EXPECT_THAT(redacted, Not(HasSubstr("read-token")));
  EXPECT_THAT(redacted, HasSubstr("# the lab PC")) << "comments and layout stay";
  EXPECT_THAT(redacted, HasSubstr("model = \"T2\""));
  // A token spelled with escapes, and one only the running config knows.
  ApiSection running;
  running.tokens = {"runtime-token-abcdefghij"};
  const std::string escaped = redact_config_secrets(
      std::string(kMinimal) +
          "[api]\ntokens = [\"esc\\u0061ped-token-0123456789\"]\n# runtime-token-abcdefghij\n",
      running);
  EXPECT_THAT(escaped, Not(HasSubstr("ped-token-0123456789"))) << escaped;
  EXPECT_THAT(escaped, Not(HasSubstr("runtime-token")));
  EXPECT_THAT(escaped, HasSubstr("<redacted>"));
  EXPECT_THAT(escaped, HasSubstr("latitude_deg = 31.")) << "the rest stays";
  EXPECT_THAT(redact_config_secrets("tokens = [\"unterminated-token-0123"),
              Not(HasSubstr("unterminated")));
}

TEST(SimEndpoints, RoundTripThroughAFile) {
  const auto dir =
      std::filesystem::temp_directory_path() / ("gyrotherm-ep-" + std::to_string(::getpid()));
  const std::string path = (dir / "ep.toml").string();
  SimEndpoints ep{"127.0.0.1", 40123, "/dev/pts/7", 4242, "/tmp/sim.sock", 250.0};
  ASSERT_TRUE(write_sim_endpoints(path, ep).ok());
  auto back = read_sim_endpoints(path);
  ASSERT_TRUE(back.ok()) << back.error().message;
  EXPECT_DOUBLE_EQ(back->time_scale, 250.0);
  EXPECT_EQ(back->modbus_port, 40123);
  EXPECT_EQ(back->gyro_device, "/dev/pts/7");
  EXPECT_EQ(back->pid, 4242);
  EXPECT_EQ(back->control_socket, "/tmp/sim.sock");
  auto cfg = parse_station_config(kMinimal, "min.toml");
  ASSERT_TRUE(cfg.ok());
  apply_sim_endpoints(*cfg, *back);
  EXPECT_EQ(cfg->chamber.endpoint.port, 40123);
  EXPECT_EQ(cfg->probes.endpoint.port, 40123);
  EXPECT_EQ(cfg->gyro.serial.device, "/dev/pts/7");
  std::filesystem::remove_all(dir);
}

// [table]: every key read; absent, the station has no table.
TEST(TableConfig, AbsentMeansNoTable) {
  auto cfg = parse_station_config(kMinimal, "min.toml");
  ASSERT_TRUE(cfg.ok()) << cfg.error().message;
  EXPECT_FALSE(cfg->table.has_value());
  EXPECT_FALSE(station_limits(*cfg).table.has_value());
}

TEST(TableConfig, EveryKeyIsRead) {
  auto cfg = parse_station_config(std::string(kMinimal) + R"(
[table]
profile = "acutrol"
host = "10.0.0.7"
port = 9888
reply_header = "binary-be"
axis = 2
timeout_s = 0.5
max_rate_dps = 1000
max_accel_dps2 = 4200
at_rate_tolerance_dps = 0.1
at_rate_tolerance_ppm = 200
at_rate_hold_s = 2
spin_up_timeout_s = 60
rest_rate_dps = 0.02
silent_timeout_s = 5
respin_after_fault = true
sensitive_axis = "radial"
heading_at_zero_deg = 90
)",
                                  "t.toml");
  ASSERT_TRUE(cfg.ok()) << cfg.error().message;
  ASSERT_TRUE(cfg->table.has_value());
  const TableSection& t = *cfg->table;
  EXPECT_EQ(t.connection.profile, "acutrol");
  EXPECT_EQ(t.connection.host, "10.0.0.7");
  EXPECT_EQ(t.connection.port, 9888);
  EXPECT_EQ(t.connection.reply_header, "binary-be");
  EXPECT_EQ(t.connection.axis, 2);
  EXPECT_DOUBLE_EQ(t.connection.timeout_s, 0.5);
  EXPECT_DOUBLE_EQ(t.max_rate_dps, 1000);
  EXPECT_DOUBLE_EQ(t.max_accel_dps2, 4200);
  EXPECT_DOUBLE_EQ(t.at_rate_tolerance_dps, 0.1);
  EXPECT_DOUBLE_EQ(t.at_rate_tolerance_ppm, 200);
  EXPECT_DOUBLE_EQ(t.at_rate_hold_s, 2);
  EXPECT_DOUBLE_EQ(t.spin_up_timeout_s, 60);
  EXPECT_DOUBLE_EQ(t.rest_rate_dps, 0.02);
  EXPECT_DOUBLE_EQ(t.silent_timeout_s, 5);
  EXPECT_TRUE(t.respin_after_fault);
  EXPECT_EQ(t.sensitive_axis, "radial");
  EXPECT_DOUBLE_EQ(t.heading_at_zero_deg, 90);
  const auto limits = station_limits(*cfg);
  ASSERT_TRUE(limits.table.has_value());

  auto aero = parse_station_config(std::string(kMinimal) + R"(
[table]
profile = "aero"
device = "/dev/ttyS1"
baud = 19200
)",
                                   "a.toml");
  ASSERT_TRUE(aero.ok()) << aero.error().message;
  EXPECT_EQ(aero->table->connection.device, "/dev/ttyS1");
  EXPECT_EQ(aero->table->connection.baud, 19200);
  // Defaults where not given.
  auto defaults = parse_station_config(std::string(kMinimal) + "[table]\n", "d.toml");
  ASSERT_TRUE(defaults.ok()) << defaults.error().message;
  EXPECT_EQ(defaults->table->connection.profile, "acutrol");
  EXPECT_EQ(defaults->table->connection.port, 9878);
  EXPECT_EQ(defaults->table->connection.reply_header, "ascii");
  EXPECT_DOUBLE_EQ(defaults->table->max_rate_dps, 500.0);
  EXPECT_FALSE(defaults->table->respin_after_fault) << "the lab's default: a person resumes";
}

TEST(TableConfig, BadValuesNameFileLineAndKey) {
  auto cfg = parse_station_config(std::string(kMinimal) + R"([table]
profile = "contraves"
port = 70000
reply_header = "hex"
axis = 0
timeout_s = 0
max_rate_dps = -5
max_accel_dps2 = 0
sensitive_axis = "vertical"
spin_rate = 3
host = "no host"
baud = -1
)",
                                  "bad.toml");
  ASSERT_FALSE(cfg.ok());
  const std::string& m = cfg.error().message;
  // kMinimal ends on line 9; [table] is line 10.
  EXPECT_THAT(m,
              HasSubstr("bad.toml:11: table.profile: \"contraves\" is not one of: acutrol, aero"));
  EXPECT_THAT(m, HasSubstr("bad.toml:12: table.port: 70000 is not a TCP port"));
  EXPECT_THAT(m,
              HasSubstr("bad.toml:13: table.reply_header: \"hex\" is not one of: ascii, binary-le, "
                        "binary-be, line"));
  EXPECT_THAT(m, HasSubstr("bad.toml:14: table.axis: 0 is not an axis number"));
  EXPECT_THAT(m, HasSubstr("bad.toml:15: table.timeout_s: 0 must be positive"));
  EXPECT_THAT(m, HasSubstr("bad.toml:16: table.max_rate_dps: -5 must be positive"));
  EXPECT_THAT(m, HasSubstr("bad.toml:17: table.max_accel_dps2: 0 must be positive"));
  EXPECT_THAT(m, HasSubstr("bad.toml:18: table.sensitive_axis: \"vertical\" is not one of"));
  EXPECT_THAT(m, HasSubstr("bad.toml:19: table.spin_rate: unknown key"));
  EXPECT_THAT(m, HasSubstr("bad.toml:20: table.host:"));
  EXPECT_THAT(m, HasSubstr("bad.toml:21: table.baud: must be positive"));
}

TEST(TableConfig, AeroNeedsADeviceUnlessSimulated) {
  auto cfg =
      parse_station_config(std::string(kMinimal) + "[table]\nprofile = \"aero\"\n", "a.toml");
  ASSERT_FALSE(cfg.ok());
  EXPECT_THAT(cfg.error().message, HasSubstr("a.toml:10: table.device: missing"));
  auto sim = parse_station_config(std::string(kMinimal) +
                                      "[table]\nprofile = \"aero\"\n"
                                      "[simulator]\nendpoints_file = \"ep.toml\"\n",
                                  "s.toml");
  EXPECT_TRUE(sim.ok()) << sim.error().message;
}

// [table] transport: the link under the protocol. Absent, each profile's
// own port (acutrol: TCP, aero: serial), so configs from before the key read
// as they did; either protocol runs on either transport.
TEST(TableConfig, TransportDefaultsByProfileAndEitherProtocolTakesEither) {
  const auto table = [](const std::string& body) {
    return parse_station_config(std::string(kMinimal) + "[table]\n" + body, "t.toml");
  };
  auto acutrol = table("");
  ASSERT_TRUE(acutrol.ok()) << acutrol.error().message;
  EXPECT_EQ(acutrol->table->connection.transport, "tcp");
  EXPECT_EQ(acutrol->table->connection.host, "192.168.53.1");
  auto aero = table("profile = \"aero\"\ndevice = \"/dev/ttyS1\"\n");
  ASSERT_TRUE(aero.ok()) << aero.error().message;
  EXPECT_EQ(aero->table->connection.transport, "serial");

  auto acl_serial = table("transport = \"serial\"\ndevice = \"/dev/ttyUSB3\"\nbaud = 19200\n");
  ASSERT_TRUE(acl_serial.ok()) << acl_serial.error().message;
  EXPECT_EQ(acl_serial->table->connection.profile, "acutrol");
  EXPECT_EQ(acl_serial->table->connection.transport, "serial");
  EXPECT_EQ(acl_serial->table->connection.device, "/dev/ttyUSB3");
  EXPECT_EQ(acl_serial->table->connection.baud, 19200);

  auto aero_tcp =
      table("profile = \"aero\"\ntransport = \"tcp\"\nhost = \"10.0.0.9\"\nport = 4001\n");
  ASSERT_TRUE(aero_tcp.ok()) << aero_tcp.error().message;
  EXPECT_EQ(aero_tcp->table->connection.transport, "tcp");
  EXPECT_EQ(aero_tcp->table->connection.host, "10.0.0.9");
  EXPECT_EQ(aero_tcp->table->connection.port, 4001);
}

// What the chosen transport needs and is not given: an error naming the
// file, the key and what is wrong (and whence the transport came).
TEST(TableConfig, ATransportWithoutItsKeysNamesTheMissingKey) {
  const auto errors = [](const std::string& body) {
    auto cfg = parse_station_config(std::string(kMinimal) + "[table]\n" + body, "t.toml");
    return cfg.ok() ? std::string("(accepted)") : cfg.error().message;
  };
  // [table] is line 10.
  EXPECT_THAT(errors("transport = \"serial\"\n"),
              HasSubstr("t.toml:10: table.device: missing: transport = \"serial\" needs the "
                        "serial device"));
  EXPECT_THAT(errors("profile = \"aero\"\n"),
              HasSubstr("t.toml:10: table.device: missing: transport is \"serial\" (profile "
                        "aero's default) needs the serial device"));
  const std::string aero_tcp = errors("profile = \"aero\"\ntransport = \"tcp\"\n");
  EXPECT_THAT(aero_tcp, HasSubstr("t.toml:10: table.host: missing: transport = \"tcp\" needs the "
                                  "serial server's host (profile aero has no default address"));
  EXPECT_THAT(aero_tcp, HasSubstr("t.toml:10: table.port: missing:"));
  EXPECT_THAT(errors("profile = \"aero\"\ntransport = \"tcp\"\nhost = \"10.0.0.9\"\n"),
              AllOf(HasSubstr("table.port: missing"), Not(HasSubstr("table.host"))));
  EXPECT_THAT(errors("transport = \"usb\"\n"),
              HasSubstr("t.toml:11: table.transport: \"usb\" is not one of: tcp, serial"));
  // The simulator names the device or port itself.
  EXPECT_EQ(errors("profile = \"aero\"\ntransport = \"tcp\"\n"
                   "[simulator]\nendpoints_file = \"ep.toml\"\n"),
            "(accepted)");
  EXPECT_EQ(errors("transport = \"serial\"\n[simulator]\nendpoints_file = \"ep.toml\"\n"),
            "(accepted)");
}

// A key of the other transport contradicts the one in force: refused, not
// ignored (the station would talk to something the file does not say).
TEST(TableConfig, AKeyOfTheOtherTransportIsAContradiction) {
  const auto errors = [](const std::string& body) {
    auto cfg = parse_station_config(std::string(kMinimal) + "[table]\n" + body, "t.toml");
    return cfg.ok() ? std::string("(accepted)") : cfg.error().message;
  };
  EXPECT_THAT(errors("profile = \"aero\"\ndevice = \"/dev/ttyS1\"\nhost = \"10.0.0.9\"\n"),
              HasSubstr("t.toml:13: table.host: given, but transport is \"serial\" (profile "
                        "aero's default): host is for transport = \"tcp\""));
  EXPECT_THAT(errors("transport = \"tcp\"\ndevice = \"/dev/ttyS1\"\n"),
              HasSubstr("t.toml:12: table.device: given, but transport = \"tcp\": device is for "
                        "transport = \"serial\""));
  EXPECT_THAT(errors("baud = 19200\n"),
              HasSubstr("t.toml:11: table.baud: given, but transport is \"tcp\" (profile "
                        "acutrol's default): baud is for transport = \"serial\""));
  EXPECT_THAT(errors("transport = \"serial\"\ndevice = \"/dev/ttyS1\"\nport = 9878\n"),
              HasSubstr("t.toml:13: table.port: given, but transport = \"serial\""));
}

TEST(SimEndpoints, TableEndpointsRoundTripAndApply) {
  const auto dir =
      std::filesystem::temp_directory_path() / ("gyrotherm-ep-table-" + std::to_string(::getpid()));
  const std::string path = (dir / "ep.toml").string();
  SimEndpoints ep{"127.0.0.1", 40123, "/dev/pts/7", 4242, "", 0};
  ep.table_port = 40999;
  ep.table_device = "/dev/pts/9";
  ASSERT_TRUE(write_sim_endpoints(path, ep).ok());
  auto back = read_sim_endpoints(path);
  ASSERT_TRUE(back.ok()) << back.error().message;
  EXPECT_EQ(back->table_port, 40999);
  EXPECT_EQ(back->table_device, "/dev/pts/9");

  // No [table]: nothing to apply.
  auto none = parse_station_config(kMinimal, "min.toml");
  ASSERT_TRUE(none.ok());
  apply_sim_endpoints(*none, *back);
  EXPECT_FALSE(none->table.has_value());
  // acutrol: loopback and the simulator's port.
  auto acutrol =
      parse_station_config(std::string(kMinimal) + "[table]\nhost = \"10.0.0.7\"\n", "t.toml");
  ASSERT_TRUE(acutrol.ok());
  apply_sim_endpoints(*acutrol, *back);
  EXPECT_EQ(acutrol->table->connection.host, "127.0.0.1");
  EXPECT_EQ(acutrol->table->connection.port, 40999);
  // aero: the simulator's pty.
  auto aero = parse_station_config(
      std::string(kMinimal) + "[table]\nprofile = \"aero\"\ndevice = \"/dev/ttyS1\"\n", "a.toml");
  ASSERT_TRUE(aero.ok());
  apply_sim_endpoints(*aero, *back);
  EXPECT_EQ(aero->table->connection.device, "/dev/pts/9");

  // Each protocol on the other transport: ACL on the simulator's second
  // pty, AERO on its own TCP port; from an older simulator that serves
  // neither, the configured link stays.
  EXPECT_EQ(back->table_acl_device, "");
  ep.table_acl_device = "/dev/pts/11";
  ep.table_aero_port = 41000;
  ASSERT_TRUE(write_sim_endpoints(path, ep).ok());
  auto both = read_sim_endpoints(path);
  ASSERT_TRUE(both.ok()) << both.error().message;
  EXPECT_EQ(both->table_acl_device, "/dev/pts/11");
  EXPECT_EQ(both->table_aero_port, 41000);
  auto acl_serial = parse_station_config(
      std::string(kMinimal) + "[table]\ntransport = \"serial\"\ndevice = \"/dev/ttyS1\"\n",
      "s.toml");
  ASSERT_TRUE(acl_serial.ok()) << acl_serial.error().message;
  auto acl_serial_old = *acl_serial;
  apply_sim_endpoints(*acl_serial, *both);
  EXPECT_EQ(acl_serial->table->connection.device, "/dev/pts/11");
  apply_sim_endpoints(acl_serial_old, *back);
  EXPECT_EQ(acl_serial_old.table->connection.device, "/dev/ttyS1");
  auto aero_tcp = parse_station_config(std::string(kMinimal) +
                                           "[table]\nprofile = \"aero\"\ntransport = \"tcp\"\n"
                                           "host = \"10.0.0.9\"\nport = 4001\n",
                                       "a.toml");
  ASSERT_TRUE(aero_tcp.ok()) << aero_tcp.error().message;
  auto aero_tcp_old = *aero_tcp;
  apply_sim_endpoints(*aero_tcp, *both);
  EXPECT_EQ(aero_tcp->table->connection.host, "127.0.0.1");
  EXPECT_EQ(aero_tcp->table->connection.port, 41000);
  apply_sim_endpoints(aero_tcp_old, *back);
  EXPECT_EQ(aero_tcp_old.table->connection.port, 4001);

  // An older simulator's file without table keys still reads.
  SimEndpoints old{"127.0.0.1", 40123, "/dev/pts/7", 4242, "", 0};
  ASSERT_TRUE(write_sim_endpoints(path, old).ok());
  auto old_back = read_sim_endpoints(path);
  ASSERT_TRUE(old_back.ok());
  EXPECT_EQ(old_back->table_port, 0);
  EXPECT_EQ(old_back->table_device, "");
  std::filesystem::remove_all(dir);
}

// Issue 15 item 19: a daemon and a simulator at different time scales.
TEST(SimEndpoints, TimeScaleMismatchIsNamed) {
  SimEndpoints ep;
  ep.time_scale = 200;
  EXPECT_EQ(sim_time_scale_mismatch(ep, 200.0, "ep.toml"), "");
  const std::string why = sim_time_scale_mismatch(ep, 100.0, "ep.toml");
  EXPECT_THAT(why, HasSubstr("time scale 200 (ep.toml)"));
  EXPECT_THAT(why, HasSubstr("asked for 100"));
  ep.time_scale = 0;  // an older simulator's file says nothing
  EXPECT_EQ(sim_time_scale_mismatch(ep, 100.0, "ep.toml"), "");
}

}  // namespace
TEST(Config, AnalysisModelAndTausAreCheckedNamingTheKey) {
  auto defaults = parse_station_config(std::string(kMinimal), "t.toml");
  ASSERT_TRUE(defaults.ok()) << defaults.error().message;
  EXPECT_EQ(defaults->analysis.model, "T4+R1+G1");
  EXPECT_EQ(defaults->analysis.allan_taus, "octave");

  auto set = parse_station_config(
      std::string(kMinimal) + "[analysis]\nmodel = \"G1 + T2\"\nallan_taus = \"decade\"\n",
      "t.toml");
  ASSERT_TRUE(set.ok()) << set.error().message;
  EXPECT_EQ(set->analysis.model, "T2+G1") << "stored in canonical form";
  EXPECT_EQ(set->analysis.allan_taus, "decade");

  auto bad = parse_station_config(
      std::string(kMinimal) + "[analysis]\nmodel = \"T5+X1\"\nallan_taus = \"weekly\"\n", "t.toml");
  ASSERT_FALSE(bad.ok());
  EXPECT_THAT(bad.error().message, HasSubstr("analysis.model:"));
  EXPECT_THAT(bad.error().message, HasSubstr("T5"));
  EXPECT_THAT(bad.error().message, HasSubstr("analysis.allan_taus:"));
  EXPECT_THAT(bad.error().message, HasSubstr("weekly"));
}

TEST(Config, ExportLocalTimeIsHhMm) {
  auto ok =
      parse_station_config(std::string(kMinimal) + "[export]\nlocal_time = \"23:59\"\n", "t.toml");
  ASSERT_TRUE(ok.ok()) << ok.error().message;
  EXPECT_EQ(ok->export_.local_time, "23:59");
  for (const char* bad : {"2:30", "24:00", "02:30:00"}) {
    auto r = parse_station_config(
        std::string(kMinimal) + "[export]\nlocal_time = \"" + bad + "\"\n", "t.toml");
    ASSERT_FALSE(r.ok()) << bad;
    EXPECT_THAT(r.error().message, HasSubstr("export.local_time:")) << bad;
    EXPECT_THAT(r.error().message, HasSubstr(bad));
  }
}

TEST(Config, ExportTimeZoneAndNightly) {
  auto ok = parse_station_config(std::string(kMinimal) +
                                     "[export]\nnightly = false\ndirectory = \"out\"\n"
                                     "time_zone = \"CET-1CEST,M3.5.0,M10.5.0/3\"\n",
                                 "t.toml");
  ASSERT_TRUE(ok.ok()) << ok.error().message;
  EXPECT_FALSE(ok->export_.nightly);
  EXPECT_EQ(ok->export_.directory, "out");
  EXPECT_EQ(ok->export_.time_zone, "CET-1CEST,M3.5.0,M10.5.0/3");
  auto defaults = parse_station_config(std::string(kMinimal), "t.toml");
  ASSERT_TRUE(defaults.ok()) << defaults.error().message;
  EXPECT_TRUE(defaults->export_.nightly);
  EXPECT_EQ(defaults->export_.time_zone, "");

  auto bad_zone = parse_station_config(
      std::string(kMinimal) + "[export]\ntime_zone = \"Mars/Olympus\"\n", "t.toml");
  ASSERT_FALSE(bad_zone.ok());
  EXPECT_THAT(bad_zone.error().message, HasSubstr("export.time_zone:"));
  EXPECT_THAT(bad_zone.error().message, HasSubstr("Mars/Olympus"));
  auto empty_dir =
      parse_station_config(std::string(kMinimal) + "[export]\ndirectory = \"\"\n", "t.toml");
  ASSERT_FALSE(empty_dir.ok());
  EXPECT_THAT(empty_dir.error().message, HasSubstr("export.directory:"));
}

// Each key in range, but together not what the sequencer can run with: the
// error names the file, line and key (SequencerOptions::is_valid).
TEST(Config, SequencerOptionCombinationsAreRefusedAtTheirKey) {
  auto cfg = parse_station_config(std::string(kMinimal), "t.toml");
  ASSERT_TRUE(cfg.ok()) << cfg.error().message;
  std::string why;
  EXPECT_TRUE(sequencer_options(*cfg).is_valid(&why)) << why;

  auto hysteresis = parse_station_config(
      std::string(kMinimal) + "[interlocks]\nprobe_disagreement_c = 0.5\nhysteresis_c = 0.5\n",
      "i.toml");
  ASSERT_FALSE(hysteresis.ok());
  EXPECT_THAT(hysteresis.error().message,
              HasSubstr("i.toml:12: interlocks.hysteresis_c: interlocks.hysteresis_c = 0.5 must be "
                        "below probe_disagreement_c = 0.5"));

  auto spin_up = parse_station_config(
      std::string(kMinimal) + "[table]\nat_rate_hold_s = 30\nspin_up_timeout_s = 20\n", "s.toml");
  ASSERT_FALSE(spin_up.ok());
  EXPECT_THAT(spin_up.error().message,
              HasSubstr("s.toml:12: table.spin_up_timeout_s: spin_up_timeout_s = 20 must be"));
  EXPECT_THAT(spin_up.error().message, HasSubstr("above at_rate_hold_s = 30"));

  // The [table]'s silent timeout becomes the table_silent interlock's.
  auto table =
      parse_station_config(std::string(kMinimal) + "[table]\nsilent_timeout_s = 4\n", "t.toml");
  ASSERT_TRUE(table.ok()) << table.error().message;
  EXPECT_DOUBLE_EQ(sequencer_options(*table).interlocks.table_timeout_s, 4);
}

}  // namespace gyrotherm::config
