// Station configuration (config/station.toml shows every key; docs/operations.md,
// "Configure"; the device maps: docs/devices.md), loaded from TOML.
//
// Every section and key is checked: unknown keys and bad values are errors
// naming file, line and key, all reported at once. Relative paths in the file
// are taken relative to the current working directory. Defaults are the
// values documented in config/station.toml.
#pragma once

#include <cstddef>
#include <memory>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "gyrotherm/analysis/table1.h"
#include "gyrotherm/core/result.h"
#include "gyrotherm/drivers/dut_link.h"
#include "gyrotherm/drivers/gyro_reader.h"
#include "gyrotherm/drivers/modbus_device.h"
#include "gyrotherm/drivers/rate_table.h"
#include "gyrotherm/drivers/registers.h"
#include "gyrotherm/drivers/serial_port.h"
#include "gyrotherm/schedules/interlocks.h"
#include "gyrotherm/schedules/schedule.h"
#include "gyrotherm/schedules/sequencer.h"

// toml++ 3's table, declared only: this header is included far more widely
// than TOML is read, and only the raw [simulator] table below names it.
// config.cpp includes toml++ and checks the version.
namespace toml {
inline namespace v3 {
class table;
}  // namespace v3
}  // namespace toml

namespace gyrotherm::config {

// An optional toml::table held through a pointer, so that users of this
// header need not see toml++: the part of std::optional's interface that
// StationConfig::simulator_table is used with. Moves keep the table (and its
// source lines); copies copy it (toml++ copies drop source lines).
class OptionalTomlTable {
 public:
  OptionalTomlTable() noexcept;
  OptionalTomlTable(const OptionalTomlTable& other);
  OptionalTomlTable(OptionalTomlTable&& other) noexcept;
  OptionalTomlTable& operator=(const OptionalTomlTable& other);
  OptionalTomlTable& operator=(OptionalTomlTable&& other) noexcept;
  ~OptionalTomlTable();

  // Holds `table` (moved: its source lines are kept).
  OptionalTomlTable& operator=(toml::table&& table);

  bool has_value() const noexcept { return table_ != nullptr; }
  explicit operator bool() const noexcept { return has_value(); }
  // Only when has_value().
  toml::table& operator*() noexcept { return *table_; }
  const toml::table& operator*() const noexcept { return *table_; }
  toml::table* operator->() noexcept { return table_.get(); }
  const toml::table* operator->() const noexcept { return table_.get(); }

 private:
  std::unique_ptr<toml::table> table_;
};

struct StationSection {
  std::string name = "station";
  double latitude_deg = 0.0;
  analysis::AxisOrientation orientation = analysis::AxisOrientation::kUp;
  double min_temp_c = -20.0;
  double max_temp_c = 60.0;
  double max_ramp_c_per_min = 2.0;
  double safe_setpoint_c = 23.0;  // where abort and shutdown leave the chamber
};

struct ChamberSection {
  drivers::ModbusEndpoint endpoint;
  std::string profile = "watlow-f4t";  // or "custom" when [chamber.registers] is given
  drivers::ChamberMap map;
  double silent_timeout_s = 10.0;  // station s without a good reading = device silent
  // After the controller took the axis off the run's demand (a fault, a
  // reset or a restart of the controller, the servo opened at its panel):
  // false, the run pauses with the table at rest until the operator resumes
  // it; true, the station closes the servo and spins the table back up by
  // itself. Either way acquisition waits for the table at rate again.
  bool respin_after_fault = false;
};

struct ProbesSection {
  drivers::ModbusEndpoint endpoint;
  std::string profile = "generic";
  drivers::RegisterSpec top;
  drivers::RegisterSpec side;
  int top_channel = 0;
  int side_channel = 1;
  double silent_timeout_s = 10.0;
};

struct GyroSection {
  // [gyro] serial and model (optional): the DUT's identity when the older
  // form is used; "" = the unnamed gyro.
  std::string serial_number;
  std::string model;
  drivers::SerialOptions serial;
  std::string protocol = "kvh1750";
  drivers::GyroFormat format;
  double silent_timeout_s = 5.0;  // station s without a sample = stream lost
};

// [[dut]]: one device under test (docs/configuration.md). A config with
// the older single [gyro] section (and no [[dut]]) reads as one DUT whose
// serial is [gyro] serial ("" when not given) and whose axes are the one
// [gyro] axis. StationConfig::duts is what the station uses; `gyro` is kept
// filled from duts[0] for code that shows "the gyro".
struct DutProbes {
  // Optional probes on this DUT's shell, read from the [probes] module
  // (same endpoint and register layout as top/side, these channels).
  int top_channel = 0;
  int side_channel = 0;
};
struct DutSection {
  std::string serial;  // the DUT's serial number; unique among [[dut]]
  std::string model;   // e.g. "KVH 1750"
  drivers::DutLink link;
  // The rate axes analysed (Table I, Allan, fits), "x"/"y"/"z" among the
  // protocol's rate channels; default: every rate channel it carries.
  std::vector<std::string> axes;
  // Each analysed axis's direction, for the Earth-rate removal: up, down,
  // horizontal. Default "up" for the primary axis, "horizontal" for others.
  std::vector<std::pair<std::string, analysis::AxisOrientation>> orientation;
  // heading_deg = { x = 90.0 }: per horizontal axis, the azimuth its
  // positive direction points to, degrees clockwise from true north seen
  // from above (on a rate table: at table position 0; the axis turns with
  // the table). Its Earth-rate component is Ω·cos φ·cos(heading). A
  // horizontal axis without one is taken as east–west (component 0), as
  // before headings existed, and the config's warnings say so.
  std::vector<std::pair<std::string, double>> heading_deg;
  std::string primary_axis;  // shown first (status, dashboard); default the last of axes
  // The axis along the rate table's spin axis (scale factor); default primary_axis.
  std::string table_axis;
  double silent_timeout_s = 5.0;  // station s without a frame = stream lost
  // A required DUT that goes silent holds the run (gyro_lost); one that is
  // not is marked lost (an event names it), its acquisition ends, and the
  // run goes on with the others.
  bool required = true;
  std::optional<DutProbes> probes;
};

// At most this many [[dut]] (the station reads each on its own thread and
// serial line).
inline constexpr std::size_t kMaxDuts = 8;

// The [[dut]] whose serial is `serial`; nullptr when none is.
const DutSection* find_dut(const std::vector<DutSection>& duts, std::string_view serial);
// The direction `dut` gives `axis` (DutSection::orientation); nullopt when
// the axis is not analysed.
std::optional<analysis::AxisOrientation> axis_orientation(const DutSection& dut,
                                                          std::string_view axis);
// The heading `dut` gives `axis` (DutSection::heading_deg); nullopt when none.
std::optional<double> axis_heading_deg(const DutSection& dut, std::string_view axis);

// [table]: the rate table. Absent from station.toml: the station has no
// table (schedules that ask for a rate are refused; static steps need none).
struct TableSection {
  drivers::TableConnection connection;
  // The station's working limits, which schedules are checked against; at
  // start-up they are checked against what the controller reports (limits()).
  double max_rate_dps = 500.0;
  double max_accel_dps2 = 100.0;
  // A rate step's dwell starts once |measured − demanded| has stayed within
  // max(at_rate_tolerance_dps, at_rate_tolerance_ppm of the demand) for
  // at_rate_hold_s; it must within spin_up_timeout_s.
  double at_rate_tolerance_dps = 0.05;
  double at_rate_tolerance_ppm = 1000.0;  // of the demand, when larger
  double at_rate_hold_s = 1.0;
  double spin_up_timeout_s = 120.0;
  // At rest: |rate| below this (the safe state then opens the interlock).
  double rest_rate_dps = 0.01;
  double silent_timeout_s = 10.0;  // station s without a good reading = device silent
  // After the controller took the axis off the run's demand (a fault, a
  // reset or a restart of the controller, the servo opened at its panel):
  // false, the run pauses with the table at rest until the operator resumes
  // it; true, the station closes the servo and spins the table back up by
  // itself. Either way acquisition waits for the table at rate again.
  bool respin_after_fault = false;
  // The gyro's sensitive axis, for the Earth-rate projection of a static
  // position: "along_table" (parallel to the table's vertical axis: Ω·sin φ,
  // whatever the position) or "radial" (horizontal, turning with the table:
  // Ω·cos φ·cos(heading_at_zero_deg + position)).
  std::string sensitive_axis = "along_table";
  double heading_at_zero_deg = 0.0;  // azimuth from north, clockwise, at position 0
};

struct StorageSection {
  std::string db_path = "gyrotherm.db";
  double commit_interval_s = 0.5;  // wall seconds
  int db_line = 0;                 // of `db` in the config file (0: not given)
};

struct ApiSection {
  std::string bind = "127.0.0.1";
  int port = 8750;  // 0 = pick a free port (it is logged and written to status_file)
  // Access (docs/api.md, "Access"): control tokens may read and change,
  // read tokens only read; each at least 16 characters, none in both lists
  // or twice. read_access "open": reads need no token; "token": every GET
  // under /api/v1 and /metrics needs a read or control token.
  std::vector<std::string> tokens;
  std::vector<std::string> read_tokens;
  std::string read_access = "open";  // or "token"
  // Unknown tokens from one address within 60 wall s before its requests
  // that need a token get 429 (for 60 s).
  int max_auth_failures = 10;
  // HTTP limits (wall time): a request must arrive within read_timeout_s; a
  // stream client further behind than stream_queue_bytes is dropped.
  double read_timeout_s = 10;
  int max_connections = 64;
  int64_t max_header_bytes = 8 * 1024;
  int64_t max_body_bytes = 64 * 1024;
  int max_stream_clients = 32;
  int64_t stream_queue_bytes = 256 * 1024;
  std::string web_root;  // dashboard files; "" = <gyrothermd dir>/../share/gyrotherm/web
};

struct ExportSection {
  bool nightly = true;                // the nightly export (docs/reports.md)
  std::string directory = "reports";  // one directory per export under it
  std::string local_time = "02:00";   // "HH:MM" in time_zone
  std::string time_zone;  // POSIX TZ rule, e.g. "CET-1CEST,M3.5.0,M10.5.0/3"; "" = system
};

struct AnalysisSection {
  double bin_s = 1.0;
  int ma_window = 101;
  double l0_window_s = 120.0;
  std::string model = "T4+R1+G1";  // fitted after each run, centred and paper forms
  // Tables II-IV: each run's compensated output smoothed by this many points
  // (centred moving average, full windows only) before its std; 1 = raw.
  int compare_smooth_points = 101;
  double derivative_window_s = 60.0;
  std::string allan_taus = "octave";  // octave, decade, all
  // Rate points (docs/analysis.md "Rate points"): cut from each end of
  // each acquisition window before the mean; a point whose samples are not
  // flat (first and last thirds within rate_flatness_sigma σ of their means
  // plus rate_flatness_ppm of the rate) is left out of its fit.
  double rate_guard_s = 1.0;
  double rate_flatness_sigma = 5.0;
  double rate_flatness_ppm = 500.0;
};

// [quality]: when a stored result is flagged (docs/analysis.md "Result
// quality"; analysis::QualityRules).
struct QualitySection {
  double min_coverage = 0.99;  // samples stored / expected
  double k_min = 0.5;          // scale factor K, nominal 1
  double k_max = 2.0;
  double max_nonlinearity_ppm = 10000.0;
  double max_residual_ratio = 20.0;  // drift fit residual std / the series' noise
};

struct ControlSection {
  double tick_s = 1.0;             // station seconds between control-loop ticks
  double min_tick_wall_s = 0.005;  // never tick faster than this in wall time
  // A device counts as silent (interlocks) only once it has also been silent
  // this long in wall time: at high time scales a busy machine can stall a
  // thread for more than a device timeout's worth of station time.
  double min_silent_wall_s = 1.0;
};

// [lab] (docs/lab.md): the station's place in the lab. Absent: a lone
// station (no outbox, no relay), exactly as before. station_id binds the
// database to the station (checked at start-up: one database, one id).
// The PostgreSQL connection string never sits in this file (runs store a
// copy of the config): it is read from url_file (a file holding a libpq
// URI or conninfo, one line; relative to the config file) or from the
// environment variable url_env. TLS: sslmode and the certificate files are
// passed to libpq; with relay = true each named file must exist.
struct LabSection {
  std::string station_id;  // required: [A-Za-z0-9][A-Za-z0-9._-]{0,63}
  bool relay = false;      // true: gyrothermd sends the outbox to the lab database
  std::string url_file;    // exactly one of url_file, url_env when relay is true
  std::string url_env;
  std::string
      sslmode;  // "" (libpq's default), disable, allow, prefer, require, verify-ca, verify-full
  std::string sslrootcert;  // paths, relative to the config file; "" = libpq's default
  std::string sslcert;
  std::string sslkey;
  int batch_records = 500;          // 1..100000
  int64_t batch_bytes = 4 << 20;    // 1 KiB..256 MiB
  double poll_s = 1.0;              // wall s, 0.01..3600
  double retry_min_s = 1.0;         // wall s, > 0
  double retry_max_s = 300.0;       // wall s, >= retry_min_s
  double connect_timeout_s = 10.0;  // wall s, > 0
  // The relay's PostgreSQL session: statement_timeout and lock_timeout,
  // wall s, 0.1..3600.
  double statement_timeout_s = 60.0;
  double lock_timeout_s = 10.0;
};

// The lab connection string of `lab`: url_file's text or url_env's value,
// with the TLS keys appended; error naming the file, variable or key.
Result<std::string> lab_conninfo(const LabSection& lab);

// Simulation hook: where gyrotherm-sim writes the endpoints it opened. When
// set, the daemon waits for this file at start-up and takes the chamber and
// probe host/port and the gyro device from it. The rest of [simulator] is
// read by gyrotherm-sim only.
struct SimulatorSection {
  std::string endpoints_file;
};

struct StationConfig {
  std::string source_path;
  // [interlocks]: limit_margin_c, probe_disagreement_c, hysteresis_c and
  // <kind>_grace_min per interlock kind. The limits and device timeouts are
  // filled in from [station] and the devices' silent_timeout_s.
  schedules::InterlockOptions interlocks;
  StationSection station;
  ChamberSection chamber;
  ProbesSection probes;
  GyroSection gyro;              // duts[0] in the older form (see DutSection)
  std::vector<DutSection> duts;  // at least one
  std::optional<TableSection> table;
  StorageSection storage;
  ApiSection api;
  ExportSection export_;
  AnalysisSection analysis;
  QualitySection quality;
  ControlSection control;
  SimulatorSection simulator;
  std::optional<LabSection> lab;  // nullopt: no [lab]
  // What loads but is probably not what the station is: "file:line: key:
  // message", one per entry (a horizontal axis without a heading). The
  // daemon and the simulator log them at start-up.
  std::vector<std::string> warnings;
  // Raw [simulator], for gyrotherm-sim. Keeps source lines only in the
  // StationConfig that load_station_config() returned (toml++ copies drop them).
  OptionalTomlTable simulator_table;
};

// The limits from [station] that schedules are checked against (min_temp_c,
// max_temp_c, max_ramp_c_per_min).
schedules::StationLimits station_limits(const StationConfig& config);

// The sequencer's options from the config: the safe set point, the
// interlocks and, with a [table], the at-rate gate and the table's silent
// timeout. load_station_config() refuses a config whose options are not
// valid (SequencerOptions::is_valid), naming the key.
schedules::SequencerOptions sequencer_options(const StationConfig& config);

// A warning for the log when the API is exposed beyond this machine with
// open reads (bind not a loopback address, read_access "open"); nullopt
// otherwise.
std::optional<std::string> api_exposure_warning(const ApiSection& api);

// `toml_text` (a station config file) with every token of its [api] tokens
// and read_tokens, and of `api`, replaced by "<redacted>": what may be stored
// or shown (runs.config_json). Comments and layout are kept; a token the text
// spells with escapes makes it re-serialised without comments; text that no
// longer parses is replaced by a one-line comment saying so.
std::string redact_config_secrets(std::string_view toml_text, const ApiSection& api = {});

// Whether the database's directory exists. SQLite creates the file, not its
// directory; a mistyped or unmounted directory would otherwise give an empty
// station. The error names "<file>:<line>: storage.db" (or `given_by`, e.g.
// "--db", when an option replaced the path) and the missing directory.
// Relative paths are taken from the working directory, as they are opened;
// ":memory:" and "" (a temporary database) need no directory. gyrothermd
// checks it at load; the simulator and the CLI, which may read the same file
// elsewhere, do not.
Status check_database_directory(const StationConfig& config, std::string_view given_by = {});

// Loads and validates. The error's message lists every problem, one per line.
Result<StationConfig> load_station_config(const std::string& path);
Result<StationConfig> parse_station_config(std::string_view toml_text,
                                           const std::string& source_name);

}  // namespace gyrotherm::config
