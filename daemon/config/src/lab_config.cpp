// [lab] (docs/lab.md): the station's place in the lab, and the connection
// string of the lab database that its url_file or url_env names.
#include <fmt/format.h>
#include <sys/stat.h>

#include <algorithm>
#include <cctype>
#include <cerrno>
#include <cstdlib>
#include <cstring>
#include <filesystem>

#include "config_readers.h"
#include "gyrotherm/config/config.h"
#include "gyrotherm/core/files.h"
#include "gyrotherm/core/toml_reader.h"

namespace gyrotherm::config {
namespace {

// A path from the config file, relative to the file's directory (absolute
// and empty paths as they are).
std::string relative_to_config(const std::string& path, const std::string& source) {
  if (path.empty() || std::filesystem::path(path).is_absolute()) return path;
  const std::filesystem::path dir = std::filesystem::path(source).parent_path();
  return dir.empty() ? path : (dir / path).string();
}

bool valid_lab_station_id(std::string_view id) {
  if (id.empty() || id.size() > 64) return false;
  const auto ok = [](char c, bool first) {
    return std::isalnum(static_cast<unsigned char>(c)) != 0 ||
           (!first && (c == '.' || c == '_' || c == '-'));
  };
  for (std::size_t i = 0; i < id.size(); ++i) {
    if (!ok(id[i], i == 0)) return false;
  }
  return true;
}

// [lab]'s TLS files, with relay = true. libpq skips a client certificate
// whose file is missing and connects without it, silently, and with
// sslmode = "require" skips a missing CA likewise: each named file must
// exist (its mode is visible to every user, its content perhaps only to
// the daemon's: a CLI reading the config as another user must not fail
// here). The key's mode is checked as libpq checks it at connect, and a
// certificate goes with its key.
void check_lab_tls_files(TableReader& t, const LabSection& l) {
  const auto check = [&](std::string_view key, const std::string& path) {
    if (path.empty()) return false;
    struct stat st {};
    if (::stat(path.c_str(), &st) != 0) {
      const bool relative = !t.raw()[key].value_or(std::string()).starts_with('/');
      t.error(key, fmt::format("{}: {}{}", path, std::strerror(errno),
                               relative ? " (a relative path is taken from the config file's "
                                          "directory)"
                                        : ""));
      return false;
    }
    if (!S_ISREG(st.st_mode)) {
      t.error(key, fmt::format("{} is not a regular file", path));
      return false;
    }
    if (key == "sslkey" && (st.st_uid == 0 ? (st.st_mode & (S_IWGRP | S_IXGRP | S_IRWXO)) != 0
                                           : (st.st_mode & (S_IRWXG | S_IRWXO)) != 0)) {
      t.error(key, fmt::format("{} has mode {:04o}: libpq refuses a key others can read (0600 "
                               "owned by the daemon's user, or 0640 owned by root)",
                               path, st.st_mode & 07777));
    }
    return true;
  };
  check("sslrootcert", l.sslrootcert);
  check("sslcert", l.sslcert);
  check("sslkey", l.sslkey);
  if (!l.sslcert.empty() && l.sslkey.empty()) {
    t.error("sslcert", "a client certificate needs its key: set sslkey too");
  } else if (l.sslcert.empty() && !l.sslkey.empty()) {
    t.error("sslkey", "a client key needs its certificate: set sslcert too");
  }
}

}  // namespace

namespace internal {

// [lab] (docs/configuration.md "[lab]", docs/lab.md). Paths are taken
// relative to the config file's directory (the URL file sits next to it,
// readable by the daemon only).
void read_lab(TableReader t, LabSection& l, const std::string& source) {
  if (auto id = t.required_string("station_id")) {
    if (!valid_lab_station_id(*id)) {
      t.error("station_id",
              "must be 1 to 64 letters, digits, '.', '_' or '-', starting with a letter or a "
              "digit (it names the station in the lab database)");
    } else {
      l.station_id = *id;
    }
  }
  if (auto r = t.boolean("relay")) l.relay = *r;
  // The connection string (it may hold a password) never sits here: runs
  // store the configuration. Said plainly rather than as an unknown key.
  for (const char* key : {"url", "conninfo", "password", "uri"}) {
    if (t.raw().contains(key)) {
      t.error(key,
              "the lab database's connection string never sits in the config (every run "
              "stores a copy of it): put it in a file named by url_file, or in the "
              "environment variable named by url_env");
      t.skip(key);
    }
  }
  const auto path = [&](std::string_view key, std::string& out) {
    if (auto v = t.string(key)) {
      if (v->empty()) {
        t.error(key, "must not be empty (leave the key out instead)");
      } else {
        out = relative_to_config(*v, source);
      }
    }
  };
  path("url_file", l.url_file);
  if (auto e = t.string("url_env")) {
    const bool name_ok = !e->empty() && std::all_of(e->begin(), e->end(), [](char c) {
      return std::isalnum(static_cast<unsigned char>(c)) != 0 || c == '_';
    }) && std::isdigit(static_cast<unsigned char>(e->front())) == 0;
    if (!name_ok) {
      t.error("url_env", "must be an environment variable's name (letters, digits, '_')");
    } else {
      l.url_env = *e;
    }
  }
  if (!l.url_file.empty() && !l.url_env.empty()) {
    t.error("url_env", fmt::format("both url_file (line {}) and url_env are given: set one",
                                   t.line_of("url_file")));
  } else if (l.relay && l.url_file.empty() && l.url_env.empty() && !t.raw().contains("url_file") &&
             !t.raw().contains("url_env")) {
    t.error("relay",
            "relay = true needs the lab database's address: url_file (a file holding the "
            "libpq URI or conninfo) or url_env (an environment variable holding it)");
  }
  if (auto m =
          t.choice("sslmode", {"disable", "allow", "prefer", "require", "verify-ca", "verify-full"},
                   std::nullopt)) {
    l.sslmode = *m;
  }
  path("sslrootcert", l.sslrootcert);
  path("sslcert", l.sslcert);
  path("sslkey", l.sslkey);
  if (l.relay) check_lab_tls_files(t, l);
  if (auto n = t.integer("batch_records")) {
    if (*n < 1 || *n > 100000)
      t.error("batch_records", fmt::format("{} must be in [1, 100000]", *n));
    else
      l.batch_records = static_cast<int>(*n);
  }
  if (auto n = t.integer("batch_bytes")) {
    if (*n < 1024 || *n > (int64_t{256} << 20))
      t.error("batch_bytes",
              fmt::format("{} must be in [1024, {}] (1 KiB to 256 MiB)", *n, int64_t{256} << 20));
    else
      l.batch_bytes = *n;
  }
  l.poll_s = t.number_in("poll_s", l.poll_s, 0.01, 3600.0);
  l.retry_min_s = t.number_in("retry_min_s", l.retry_min_s, 0.01, 86400.0);
  l.retry_max_s = t.number_in("retry_max_s", l.retry_max_s, 0.01, 86400.0);
  if (l.retry_max_s < l.retry_min_s) {
    t.error(t.raw().contains("retry_max_s") ? "retry_max_s" : "retry_min_s",
            fmt::format("retry_max_s ({:g}) must be at least retry_min_s ({:g})", l.retry_max_s,
                        l.retry_min_s));
  }
  l.connect_timeout_s = t.number_in("connect_timeout_s", l.connect_timeout_s, 0.1, 3600.0);
  l.statement_timeout_s = t.number_in("statement_timeout_s", l.statement_timeout_s, 0.1, 3600.0);
  l.lock_timeout_s = t.number_in("lock_timeout_s", l.lock_timeout_s, 0.1, 3600.0);
  t.finish();
}

}  // namespace internal

namespace {

std::string trimmed(std::string_view s) {
  const auto space = [](char c) { return std::isspace(static_cast<unsigned char>(c)) != 0; };
  while (!s.empty() && space(s.front())) s.remove_prefix(1);
  while (!s.empty() && space(s.back())) s.remove_suffix(1);
  return std::string(s);
}

std::string percent_encoded(std::string_view s) {
  std::string out;
  for (const char c : s) {
    const auto u = static_cast<unsigned char>(c);
    if (std::isalnum(u) != 0 || c == '-' || c == '.' || c == '_' || c == '~' || c == '/') {
      out += c;
    } else {
      out += fmt::format("%{:02X}", u);
    }
  }
  return out;
}

// A conninfo value in single quotes (backslash and quote escaped).
std::string conninfo_quoted(std::string_view s) {
  std::string out = "'";
  for (const char c : s) {
    if (c == '\\' || c == '\'') out += '\\';
    out += c;
  }
  return out + "'";
}

}  // namespace

Result<std::string> lab_conninfo(const LabSection& lab) {
  // The text is never quoted in an error: it may hold a password.
  std::string base;
  if (!lab.url_file.empty()) {
    auto text = read_bounded_file(lab.url_file, 64 * 1024);
    if (!text) {
      return Error::Permanent(
          fmt::format("[lab] url_file: cannot read {}: {}", lab.url_file, text.error().message));
    }
    base = trimmed(*text);
    if (base.empty()) {
      return Error::Permanent(fmt::format(
          "[lab] url_file: {} is empty (it should hold one line: the lab database's libpq URI "
          "or conninfo)",
          lab.url_file));
    }
    if (base.find('\n') != std::string::npos) {
      return Error::Permanent(
          fmt::format("[lab] url_file: {} holds more than one line (it should hold one: the lab "
                      "database's libpq URI or conninfo)",
                      lab.url_file));
    }
  } else if (!lab.url_env.empty()) {
    const char* value = std::getenv(lab.url_env.c_str());
    if (value) base = trimmed(value);
    if (base.empty()) {
      return Error::Permanent(fmt::format(
          "[lab] url_env: the environment variable {} is {} (it should hold the lab database's "
          "libpq URI or conninfo)",
          lab.url_env, value ? "empty" : "not set"));
    }
  } else {
    return Error::Permanent(
        "[lab]: neither url_file nor url_env is set: the lab database's address is unknown");
  }
  const bool uri = base.starts_with("postgresql://") || base.starts_with("postgres://");
  // Later keys win in libpq: the config's TLS settings override the URL's.
  for (const auto& [key, value] :
       {std::pair{"sslmode", &lab.sslmode}, std::pair{"sslrootcert", &lab.sslrootcert},
        std::pair{"sslcert", &lab.sslcert}, std::pair{"sslkey", &lab.sslkey}}) {
    if (value->empty()) continue;
    if (uri) {
      base += base.find('?') == std::string::npos ? '?' : '&';
      base += fmt::format("{}={}", key, percent_encoded(*value));
    } else {
      base += fmt::format(" {}={}", key, conninfo_quoted(*value));
    }
  }
  return base;
}

}  // namespace gyrotherm::config
