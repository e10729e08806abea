// [lab] (docs/configuration.md "[lab]", docs/lab.md): parsing, validation
// with file:line: lab.key, the connection string read from a file or the
// environment (never from the config, never in a message or a stored run).
#include <fmt/format.h>
#include <gmock/gmock.h>
#include <gtest/gtest.h>
#include <stdlib.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <string>

#include "gyrotherm/config/config.h"
#include "gyrotherm/config/run_config.h"

namespace gyrotherm::config {
namespace {

using ::testing::HasSubstr;
using ::testing::Not;

constexpr const char* kBase = R"([station]
latitude_deg = 31.9
[chamber]
port = 1502
[probes]
port = 1502
[gyro]
device = "/dev/ttyUSB0"
)";

// A password no message, status or stored config may show.
constexpr const char* kPassword = "pw-9f2c41d7e0";

class LabConfig : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = std::filesystem::temp_directory_path() /
           fmt::format("gyrotherm-lab-config-{}-{}", ::getpid(),
                       ::testing::UnitTest::GetInstance()->current_test_info()->name());
    std::filesystem::remove_all(dir_);
    std::filesystem::create_directories(dir_);
  }
  void TearDown() override { std::filesystem::remove_all(dir_); }

  void write(const std::string& name, const std::string& text) {
    std::ofstream(dir_ / name) << text;
  }
  // Writes station.toml (kBase + `lab`) in the test's folder and loads it.
  Result<StationConfig> load(const std::string& lab) {
    write("station.toml", std::string(kBase) + lab);
    return load_station_config((dir_ / "station.toml").string());
  }

  std::filesystem::path dir_;
};

TEST_F(LabConfig, AbsentMeansALoneStation) {
  auto cfg = parse_station_config(kBase, "s.toml");
  ASSERT_TRUE(cfg.ok()) << cfg.error().message;
  EXPECT_FALSE(cfg->lab.has_value());
  EXPECT_TRUE(run_config_json(*cfg)["lab"].is_null());
}

TEST_F(LabConfig, StationIdAloneQueuesWithoutRelaying) {
  auto cfg = parse_station_config(std::string(kBase) + "[lab]\nstation_id = \"st-07\"\n", "s.toml");
  ASSERT_TRUE(cfg.ok()) << cfg.error().message;
  ASSERT_TRUE(cfg->lab.has_value());
  const LabSection& l = *cfg->lab;
  EXPECT_EQ(l.station_id, "st-07");
  EXPECT_FALSE(l.relay);
  EXPECT_EQ(l.batch_records, 500);
  EXPECT_EQ(l.batch_bytes, 4 << 20);
  EXPECT_DOUBLE_EQ(l.poll_s, 1.0);
  EXPECT_DOUBLE_EQ(l.retry_min_s, 1.0);
  EXPECT_DOUBLE_EQ(l.retry_max_s, 300.0);
  EXPECT_DOUBLE_EQ(l.connect_timeout_s, 10.0);
  EXPECT_DOUBLE_EQ(l.statement_timeout_s, 60.0);
  EXPECT_DOUBLE_EQ(l.lock_timeout_s, 10.0);
}

TEST_F(LabConfig, EveryKeyIsRead) {
  write("lab.url", "postgresql://st07@lab-db.example:5433/lab\n");
  std::filesystem::create_directories(dir_ / "certs");
  write("certs/lab-ca.crt", "CA\n");
  write("st07.crt", "certificate\n");
  write("st07.key", "key\n");
  std::filesystem::permissions(
      dir_ / "st07.key", std::filesystem::perms::owner_read | std::filesystem::perms::owner_write);
  auto cfg = load(fmt::format(R"([lab]
station_id = "st-07"
relay = true
url_file = "lab.url"
sslmode = "verify-full"
sslrootcert = "certs/lab-ca.crt"
sslcert = "{0}/st07.crt"
sslkey = "{0}/st07.key"
batch_records = 2000
batch_bytes = 1048576
poll_s = 0.5
retry_min_s = 2
retry_max_s = 600
connect_timeout_s = 5
statement_timeout_s = 120
lock_timeout_s = 2.5
)",
                              dir_.string()));
  ASSERT_TRUE(cfg.ok()) << cfg.error().message;
  const LabSection& l = *cfg->lab;
  EXPECT_TRUE(l.relay);
  // Relative paths: next to the config file.
  EXPECT_EQ(l.url_file, (dir_ / "lab.url").string());
  EXPECT_EQ(l.sslrootcert, (dir_ / "certs/lab-ca.crt").string());
  EXPECT_EQ(l.sslcert, (dir_ / "st07.crt").string());
  EXPECT_EQ(l.sslkey, (dir_ / "st07.key").string());
  EXPECT_EQ(l.sslmode, "verify-full");
  EXPECT_EQ(l.batch_records, 2000);
  EXPECT_EQ(l.batch_bytes, 1048576);
  EXPECT_DOUBLE_EQ(l.poll_s, 0.5);
  EXPECT_DOUBLE_EQ(l.retry_min_s, 2);
  EXPECT_DOUBLE_EQ(l.retry_max_s, 600);
  EXPECT_DOUBLE_EQ(l.connect_timeout_s, 5);
  EXPECT_DOUBLE_EQ(l.statement_timeout_s, 120);
  EXPECT_DOUBLE_EQ(l.lock_timeout_s, 2.5);
}

// With relay = true every TLS file named must exist: libpq would connect
// without a missing client certificate, silently. The key's mode is
// checked as libpq checks it; a certificate goes with its key. Errors
// name the file, the line and the key, and the path as resolved.
TEST_F(LabConfig, TlsFilesAreCheckedAtLoad) {
  write("lab.url", "postgresql://st07@lab-db.example/lab\n");
  write("ca.crt", "CA\n");
  write("st07.crt", "certificate\n");
  write("st07.key", "key\n");
  std::filesystem::permissions(
      dir_ / "st07.key", std::filesystem::perms::owner_read | std::filesystem::perms::owner_write);
  const std::string head = "[lab]\nstation_id = \"st-07\"\nrelay = true\nurl_file = \"lab.url\"\n";
  auto cfg =
      load(head + "sslrootcert = \"ca.crt\"\nsslcert = \"st07.crt\"\nsslkey = \"st07.key\"\n");
  ASSERT_TRUE(cfg.ok()) << cfg.error().message;

  const std::string toml = (dir_ / "station.toml").string();
  cfg = load(head +
             "sslrootcert = \"missing-ca.crt\"\nsslcert = \"/nowhere/st07.crt\"\nsslkey = "
             "\"st07.key\"\n");
  ASSERT_FALSE(cfg.ok());
  EXPECT_THAT(cfg.error().message,
              HasSubstr(fmt::format("{}:13: lab.sslrootcert: {}: No such file or directory (a "
                                    "relative path is taken from the config file's directory)",
                                    toml, (dir_ / "missing-ca.crt").string())));
  EXPECT_THAT(cfg.error().message,
              HasSubstr(fmt::format("{}:14: lab.sslcert: /nowhere/st07.crt: No such file or "
                                    "directory",
                                    toml)));

  cfg = load(head + "sslcert = \"st07.crt\"\n");
  ASSERT_FALSE(cfg.ok());
  EXPECT_THAT(cfg.error().message,
              HasSubstr(":13: lab.sslcert: a client certificate needs its key: set sslkey too"));
  cfg = load(head + "sslkey = \"st07.key\"\n");
  ASSERT_FALSE(cfg.ok());
  EXPECT_THAT(cfg.error().message,
              HasSubstr(":13: lab.sslkey: a client key needs its certificate"));

  std::filesystem::permissions(dir_ / "st07.key", std::filesystem::perms::others_read,
                               std::filesystem::perm_options::add);
  cfg = load(head + "sslcert = \"st07.crt\"\nsslkey = \"st07.key\"\n");
  ASSERT_FALSE(cfg.ok());
  EXPECT_THAT(cfg.error().message,
              HasSubstr(fmt::format(":14: lab.sslkey: {} has mode 0604: libpq refuses a key "
                                    "others can read",
                                    (dir_ / "st07.key").string())));

  cfg = load(head + "sslrootcert = \".\"\n");
  ASSERT_FALSE(cfg.ok());
  EXPECT_THAT(cfg.error().message,
              HasSubstr("lab.sslrootcert: " + dir_.string() + "/. is not a regular file"));

  // relay = false: nothing connects, the files may come later.
  cfg = load("[lab]\nstation_id = \"st-07\"\nsslcert = \"later.crt\"\nsslkey = \"later.key\"\n");
  ASSERT_TRUE(cfg.ok()) << cfg.error().message;
}

TEST_F(LabConfig, ErrorsNameFileLineAndKey) {
  auto cfg = parse_station_config(std::string(kBase) + R"([lab]
station_id = "-bad id"
relay = true
sslmode = "sometimes"
batch_records = 0
batch_bytes = 10
poll_s = 0
retry_min_s = 60
retry_max_s = 30
connect_timeout_s = -1
colour = "blue"
statement_timeout_s = 0
lock_timeout_s = 7200
)",
                                  "bad.toml");
  ASSERT_FALSE(cfg.ok());
  const std::string& m = cfg.error().message;
  EXPECT_THAT(m, HasSubstr("bad.toml:10: lab.station_id: must be 1 to 64 letters"));
  EXPECT_THAT(m, HasSubstr("bad.toml:11: lab.relay: relay = true needs the lab database's "
                           "address: url_file"));
  EXPECT_THAT(m, HasSubstr("bad.toml:12: lab.sslmode: \"sometimes\" is not one of"));
  EXPECT_THAT(m, HasSubstr("bad.toml:13: lab.batch_records: 0 must be in [1, 100000]"));
  EXPECT_THAT(m, HasSubstr("bad.toml:14: lab.batch_bytes: 10 must be in [1024,"));
  EXPECT_THAT(m, HasSubstr("bad.toml:15: lab.poll_s:"));
  EXPECT_THAT(m, HasSubstr("bad.toml:17: lab.retry_max_s: retry_max_s (30) must be at least "
                           "retry_min_s (60)"));
  EXPECT_THAT(m, HasSubstr("bad.toml:18: lab.connect_timeout_s:"));
  EXPECT_THAT(m, HasSubstr("bad.toml:19: lab.colour: unknown key"));
  EXPECT_THAT(m, HasSubstr("bad.toml:20: lab.statement_timeout_s:"));
  EXPECT_THAT(m, HasSubstr("bad.toml:21: lab.lock_timeout_s:"));

  cfg = parse_station_config(std::string(kBase) + R"([lab]
relay = false
url_file = "a"
url_env = "LAB_URL"
)",
                             "two.toml");
  ASSERT_FALSE(cfg.ok());
  EXPECT_THAT(cfg.error().message, HasSubstr("two.toml:9: lab.station_id: missing"));
  EXPECT_THAT(cfg.error().message,
              HasSubstr("two.toml:12: lab.url_env: both url_file (line 11) and url_env"));

  cfg = parse_station_config(std::string(kBase) + "[lab]\nstation_id = \"a\"\nurl_env = \"1X\"\n",
                             "env.toml");
  ASSERT_FALSE(cfg.ok());
  EXPECT_THAT(cfg.error().message,
              HasSubstr("env.toml:11: lab.url_env: must be an environment variable's name"));
}

// A connection string in the config is refused, and its text (password
// included) is not repeated in the message.
TEST_F(LabConfig, AConnectionStringInTheConfigIsRefusedWithoutQuotingIt) {
  const std::string url = fmt::format("postgresql://st07:{}@lab-db/lab", kPassword);
  for (const char* key : {"url", "conninfo", "password"}) {
    SCOPED_TRACE(key);
    auto cfg = parse_station_config(
        std::string(kBase) + fmt::format("[lab]\nstation_id = \"a\"\n{} = \"{}\"\n", key, url),
        "s.toml");
    ASSERT_FALSE(cfg.ok());
    EXPECT_THAT(cfg.error().message,
                HasSubstr(fmt::format("s.toml:11: lab.{}: the lab database's connection string "
                                      "never sits in the config",
                                      key)));
    EXPECT_THAT(cfg.error().message, Not(HasSubstr(kPassword)));
    EXPECT_THAT(cfg.error().message, Not(HasSubstr("unknown key")));
  }
}

TEST_F(LabConfig, ConninfoFromAFileNextToTheConfig) {
  write("lab.url", fmt::format("  postgresql://st07:{}@lab-db:5432/lab\n\n", kPassword));
  auto cfg = load("[lab]\nstation_id = \"st-07\"\nrelay = true\nurl_file = \"lab.url\"\n");
  ASSERT_TRUE(cfg.ok()) << cfg.error().message;
  auto conninfo = lab_conninfo(*cfg->lab);
  ASSERT_TRUE(conninfo.ok()) << conninfo.error().message;
  EXPECT_EQ(*conninfo, fmt::format("postgresql://st07:{}@lab-db:5432/lab", kPassword));

  // TLS keys: query parameters of a URI (after its own), conninfo keywords
  // after a key=value string.
  LabSection l = *cfg->lab;
  l.sslmode = "verify-full";
  l.sslrootcert = "/etc/gyro therm/ca.crt";
  conninfo = lab_conninfo(l);
  ASSERT_TRUE(conninfo.ok()) << conninfo.error().message;
  EXPECT_EQ(*conninfo,
            fmt::format("postgresql://st07:{}@lab-db:5432/lab?sslmode=verify-full&sslrootcert=/"
                        "etc/gyro%20therm/ca.crt",
                        kPassword));
  write("lab.url", "postgresql://lab-db/lab?application_name=st07\n");
  conninfo = lab_conninfo(l);
  ASSERT_TRUE(conninfo.ok()) << conninfo.error().message;
  EXPECT_EQ(*conninfo,
            "postgresql://lab-db/lab?application_name=st07&sslmode=verify-full&sslrootcert=/"
            "etc/gyro%20therm/ca.crt");
  write("lab.url", fmt::format("host=lab-db dbname=lab user=st07 password={}\n", kPassword));
  l.sslkey = "/k/it's.key";
  conninfo = lab_conninfo(l);
  ASSERT_TRUE(conninfo.ok()) << conninfo.error().message;
  EXPECT_EQ(*conninfo, fmt::format("host=lab-db dbname=lab user=st07 password={} "
                                   "sslmode='verify-full' sslrootcert='/etc/gyro therm/ca.crt' "
                                   "sslkey='/k/it\\'s.key'",
                                   kPassword));
}

TEST_F(LabConfig, ConninfoErrorsNameTheFileOrVariableNeverTheText) {
  LabSection l;
  l.station_id = "st-07";
  l.relay = true;
  l.url_file = (dir_ / "missing.url").string();
  auto conninfo = lab_conninfo(l);
  ASSERT_FALSE(conninfo.ok());
  EXPECT_THAT(conninfo.error().message, HasSubstr("[lab] url_file: cannot read " + l.url_file));

  write("empty.url", " \n\t\n");
  l.url_file = (dir_ / "empty.url").string();
  conninfo = lab_conninfo(l);
  ASSERT_FALSE(conninfo.ok());
  EXPECT_THAT(conninfo.error().message, HasSubstr(l.url_file + " is empty"));

  write("two.url", fmt::format("postgresql://a:{}@x/lab\npostgresql://b@y/lab\n", kPassword));
  l.url_file = (dir_ / "two.url").string();
  conninfo = lab_conninfo(l);
  ASSERT_FALSE(conninfo.ok());
  EXPECT_THAT(conninfo.error().message, HasSubstr("holds more than one line"));
  EXPECT_THAT(conninfo.error().message, Not(HasSubstr(kPassword)));

  l.url_file.clear();
  l.url_env = "GYROTHERM_LAB_CONFIG_TEST_URL";
  ::unsetenv(l.url_env.c_str());
  conninfo = lab_conninfo(l);
  ASSERT_FALSE(conninfo.ok());
  EXPECT_THAT(conninfo.error().message,
              HasSubstr("[lab] url_env: the environment variable GYROTHERM_LAB_CONFIG_TEST_URL "
                        "is not set"));
  ::setenv(l.url_env.c_str(), "", 1);
  conninfo = lab_conninfo(l);
  ASSERT_FALSE(conninfo.ok());
  EXPECT_THAT(conninfo.error().message, HasSubstr("GYROTHERM_LAB_CONFIG_TEST_URL is empty"));
  ::setenv(l.url_env.c_str(), fmt::format("postgresql://st07:{}@lab-db/lab", kPassword).c_str(), 1);
  conninfo = lab_conninfo(l);
  ASSERT_TRUE(conninfo.ok()) << conninfo.error().message;
  EXPECT_EQ(*conninfo, fmt::format("postgresql://st07:{}@lab-db/lab", kPassword));
  ::unsetenv(l.url_env.c_str());
}

// runs.config_json keeps where the connection string is, never the string.
TEST_F(LabConfig, TheStoredConfigNamesTheFileOrVariableOnly) {
  write("lab.url", fmt::format("postgresql://st07:{}@lab-db:5432/lab\n", kPassword));
  auto cfg = load("[lab]\nstation_id = \"st-07\"\nrelay = true\nurl_file = \"lab.url\"\n");
  ASSERT_TRUE(cfg.ok()) << cfg.error().message;
  nlohmann::json stored = run_config_json(*cfg);
  EXPECT_EQ(stored["lab"]["station_id"], "st-07");
  EXPECT_EQ(stored["lab"]["relay"], true);
  EXPECT_EQ(stored["lab"]["url_file"], (dir_ / "lab.url").string());
  EXPECT_EQ(stored["lab"]["url_env"], "");
  EXPECT_THAT(stored.dump(), Not(HasSubstr(kPassword)));
  EXPECT_THAT(stored.dump(), Not(HasSubstr("lab-db")));

  ::setenv("GYROTHERM_LAB_CONFIG_TEST_URL2",
           fmt::format("postgresql://st07:{}@lab-db/lab", kPassword).c_str(), 1);
  cfg = load(
      "[lab]\nstation_id = \"st-07\"\nrelay = true\nurl_env = "
      "\"GYROTHERM_LAB_CONFIG_TEST_URL2\"\n");
  ASSERT_TRUE(cfg.ok()) << cfg.error().message;
  stored = run_config_json(*cfg);
  EXPECT_EQ(stored["lab"]["url_env"], "GYROTHERM_LAB_CONFIG_TEST_URL2");
  EXPECT_THAT(stored.dump(), Not(HasSubstr(kPassword)));
  ::unsetenv("GYROTHERM_LAB_CONFIG_TEST_URL2");
}

}  // namespace
}  // namespace gyrotherm::config
