// Memory and time of analysing one long soak from the database (issue 27,
// item 5): `gyrotherm stats`, `allan` and `fit` run as a user runs them, each
// in its own process, its peak RSS (ru_maxrss) and wall time taken; beside
// them numpy on the same samples already in memory (bench/soak_numpy.py).
//
// Data: one run of a DUT at 1 kHz (channel gyro_z, °/h): a soak at 20 °C of
// N samples (the figure named), then a soak at 40 °C of N / 10, so the
// drift fit has two temperatures. Rate: 1e3 °/h + white noise (3 °/h per
// sample) + a wandering bias (Gauss–Markov, 0.05 °/h, 300 s) + 0.01 °/h per
// °C; shell temperatures at 1 Hz. The database and the raw samples of the
// first soak (float64 t_s then rate_dph, for numpy) are built once in
// $TMPDIR and reused.
//
// Usage: gyrotherm_bench_soak [--samples 5280000,10200000] [--bin DIR]
//   --bin: where gyrotherm is (default: this program's directory).
#include <fmt/format.h>
#include <sys/resource.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <random>
#include <string>
#include <vector>

#include "gyrotherm/core/samples.h"
#include "gyrotherm/storage/database.h"
#include "gyrotherm/storage/sample_writer.h"

namespace {

namespace fs = std::filesystem;
using namespace gyrotherm;

constexpr double kRateHz = 1000.0;

fs::path scratch_dir() {
  const char* t = std::getenv("TMPDIR");
  return t != nullptr && *t != '\0' ? fs::path(t) : fs::path("/tmp");
}

void die(const std::string& why) {
  fmt::print(stderr, "gyrotherm_bench_soak: {}\n", why);
  std::exit(1);
}

// The run: soak 1 (n samples) at 20 °C, soak 2 (n / 10) at 40 °C, 60 s apart.
void build(const fs::path& db_path, const fs::path& raw_path, std::size_t n) {
  fs::remove(db_path);
  fs::remove(raw_path);
  auto db = storage::Database::open(db_path.string());
  if (!db) die(db.error().message);
  storage::RunRecord run;
  run.schedule_name = "soak memory bench";
  run.state = "acquiring";
  run.latitude_deg = 31.9;
  run.orientation = "up";
  run.config_json = R"({"station": {"name": "bench"}, "analysis": {"model": "T1"}})";
  auto id = db->create_run(run);
  if (!id) die(id.error().message);
  storage::RunDutRecord dut;
  dut.run_id = *id;
  dut.position = 0;
  dut.dut = {0, "SN-BENCH", "FOG-B", ""};
  dut.primary_axis = "z";
  dut.axes = {"z"};
  dut.rate_hz = kRateHz;
  dut.config_json = R"({"serial": "SN-BENCH", "orientation": {"z": "up"}})";
  dut.channels.push_back(
      {0, 0, 0, 0, ChannelSpec{"gyro_z", "deg/h", ChannelKind::kRate, "z", 1.0}});
  auto added = db->add_run_dut(*id, dut);
  if (!added) die(added.error().message);
  auto writer = storage::SampleWriter::start(db_path.string());
  if (!writer) die(writer.error().message);

  std::mt19937_64 rng(20261201);
  std::normal_distribution<double> g(0.0, 1.0);
  const double gm_tc_s = 300.0, gm_sigma = 0.05, dt = 1.0 / kRateHz;
  const double phi = std::exp(-dt / gm_tc_s), gm_drive = gm_sigma * std::sqrt(1 - phi * phi);
  double gm = 0;
  std::ofstream raw(raw_path, std::ios::binary);
  std::vector<double> raw_t, raw_rate;
  double from_s = 0;
  int index = 0;
  for (const auto& [setpoint_c, count] : {std::pair{20.0, n}, std::pair{40.0, n / 10}}) {
    const double to_s = from_s + static_cast<double>(count) / kRateHz;
    storage::SegmentRecord seg;
    seg.run_id = *id;
    seg.index = index++;
    seg.kind = "soak";
    seg.label = fmt::format("soak {:g} °C", setpoint_c);
    seg.setpoint_c = setpoint_c;
    seg.t_start_s = from_s;
    seg.t_end_s = to_s;
    seg.t_acquire_start_s = from_s;
    seg.t_acquire_end_s = to_s;
    seg.state = "completed";
    auto sid = db->create_segment(seg);
    if (!sid) die(sid.error().message);
    seg.id = *sid;
    seg.windows = {{from_s, to_s}};
    if (Status st = db->update_segment(seg); !st) die(st.error().message);
    std::vector<DutFrame> frames;
    for (std::size_t k = 0; k < count; ++k) {
      const double t = from_s + static_cast<double>(k) / kRateHz;
      gm = phi * gm + gm_drive * g(rng);
      DutFrame f;
      f.t_s = t;
      f.seq = static_cast<uint32_t>(k % 128);
      f.raw[0] = 1e3 + 0.01 * setpoint_c + gm + 3.0 * g(rng);
      frames.push_back(f);
      if (index == 1) {
        raw_t.push_back(t);
        raw_rate.push_back(f.raw[0]);
      }
      if (frames.size() == 1000000 || k + 1 == count) {
        (*writer)->push_frames(*added, frames);
        if (Status st = (*writer)->flush(); !st) die(st.error().message);
        frames.clear();
      }
    }
    for (double t = from_s; t < to_s; t += 1.0) {
      TemperatureSample temp;
      temp.t_s = t;
      temp.setpoint_c = temp.chamber_c = setpoint_c;
      temp.top_c = setpoint_c + 0.01;
      temp.side_c = setpoint_c - 0.01;
      (*writer)->push_temperature(*id, temp);
    }
    if (Status st = (*writer)->flush(); !st) die(st.error().message);
    from_s = to_s + 60.0;
  }
  (*writer)->stop();
  if (Status st = db->set_run_state(*id, "completed", true); !st) die(st.error().message);
  raw.write(reinterpret_cast<const char*>(raw_t.data()),
            static_cast<std::streamsize>(raw_t.size() * sizeof(double)));
  raw.write(reinterpret_cast<const char*>(raw_rate.data()),
            static_cast<std::streamsize>(raw_rate.size() * sizeof(double)));
  if (!raw) die("cannot write " + raw_path.string());
}

struct Measured {
  double wall_s = 0;
  double peak_mib = 0;
  int code = -1;
  std::string out;
};

// Runs argv with its stdout to out_path and waits: wall time, peak RSS
// (ru_maxrss) and exit code. Called in a small process (--measure): a child's
// ru_maxrss counts the pages it shared with its parent before exec, so the
// bench's own memory (the samples it wrote) must not be the parent.
Measured run_here(const std::vector<std::string>& argv, const fs::path& out_path) {
  const auto t0 = std::chrono::steady_clock::now();
  const pid_t pid = fork();
  if (pid < 0) die("fork failed");
  if (pid == 0) {
    if (!std::freopen(out_path.c_str(), "w", stdout)) _exit(126);
    std::vector<char*> args;
    for (const auto& a : argv) args.push_back(const_cast<char*>(a.c_str()));
    args.push_back(nullptr);
    execv(args[0], args.data());
    _exit(127);
  }
  int status = 0;
  rusage usage{};
  wait4(pid, &status, 0, &usage);
  Measured m;
  m.wall_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  m.peak_mib = static_cast<double>(usage.ru_maxrss) / 1024.0;
  m.code = WIFEXITED(status) ? WEXITSTATUS(status) : -1;
  return m;
}

// run_here in a fresh process of this program (`--measure OUT cmd...`),
// which prints "peak_mib wall_s code" on the pipe.
Measured run(const std::vector<std::string>& argv, const fs::path& out_path) {
  std::fflush(stdout);
  int fds[2];
  if (pipe(fds) != 0) die("pipe failed");
  const pid_t pid = fork();
  if (pid < 0) die("fork failed");
  if (pid == 0) {
    dup2(fds[1], STDOUT_FILENO);
    close(fds[0]);
    std::vector<std::string> args = {fs::canonical("/proc/self/exe").string(), "--measure",
                                     out_path.string()};
    args.insert(args.end(), argv.begin(), argv.end());
    std::vector<char*> c;
    for (const auto& a : args) c.push_back(const_cast<char*>(a.c_str()));
    c.push_back(nullptr);
    execv(c[0], c.data());
    _exit(127);
  }
  close(fds[1]);
  std::string reply;
  char buf[256];
  for (ssize_t r; (r = read(fds[0], buf, sizeof buf)) > 0;)
    reply.append(buf, static_cast<std::size_t>(r));
  close(fds[0]);
  waitpid(pid, nullptr, 0);
  Measured m;
  if (std::sscanf(reply.c_str(), "%lf %lf %d", &m.peak_mib, &m.wall_s, &m.code) != 3) {
    die("the measuring process answered '" + reply + "'");
  }
  std::ifstream in(out_path);
  m.out.assign(std::istreambuf_iterator<char>(in), {});
  return m;
}

}  // namespace

int main(int argc, char** argv) {
  if (argc >= 4 && std::string(argv[1]) == "--measure") {
    const Measured m = run_here(std::vector<std::string>(argv + 3, argv + argc), argv[2]);
    std::printf("%.3f %.6f %d\n", m.peak_mib, m.wall_s, m.code);
    return 0;
  }
  std::vector<std::size_t> sizes = {5280000, 10200000};
  fs::path bin = fs::canonical("/proc/self/exe").parent_path();
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    if (a == "--samples" && i + 1 < argc) {
      sizes.clear();
      std::string list = argv[++i];
      for (std::size_t at = 0; at < list.size();) {
        const std::size_t comma = list.find(',', at);
        sizes.push_back(std::stoull(list.substr(at, comma - at)));
        at = comma == std::string::npos ? list.size() : comma + 1;
      }
    } else if (a == "--bin" && i + 1 < argc) {
      bin = argv[++i];
    } else if (a.starts_with("--benchmark")) {
      // scripts/bench passes Google Benchmark's options to every binary
    } else {
      die("usage: gyrotherm_bench_soak [--samples N,N...] [--bin DIR]");
    }
  }
  const fs::path cli = bin / "gyrotherm";
  const fs::path source_dir = GYROTHERM_SOURCE_DIR;
  fmt::print("| samples in the soak | command | wall s | peak RSS MiB | bytes/sample |\n");
  fmt::print("|---|---|---|---|---|\n");
  for (const std::size_t n : sizes) {
    const fs::path db_path = scratch_dir() / fmt::format("gyrotherm-bench-soak-{}.db", n);
    const fs::path raw_path = scratch_dir() / fmt::format("gyrotherm-bench-soak-{}.f64", n);
    if (!fs::exists(raw_path) || fs::file_size(raw_path) != 2 * n * sizeof(double) ||
        !fs::exists(db_path)) {
      build(db_path, raw_path, n);
    }
    const fs::path out = scratch_dir() / "gyrotherm-bench-soak.out";
    const std::vector<std::pair<std::string, std::vector<std::string>>> commands = {
        {"gyrotherm stats --json",
         {cli.string(), "stats", "--db", db_path.string(), "--runs", "1", "--json"}},
        {"gyrotherm allan --json",
         {cli.string(), "allan", "--db", db_path.string(), "--run", "1", "--json"}},
        {"gyrotherm fit --json",
         {cli.string(), "fit", "--db", db_path.string(), "--runs", "1", "--json"}},
        {"numpy (samples in memory; its own timing below)",
         {"/usr/bin/python3", (source_dir / "bench" / "soak_numpy.py").string(),
          raw_path.string()}},
    };
    for (const auto& [name, args] : commands) {
      const Measured m = run(args, out);
      fmt::print("| {} | {} | {:.2f} | {:.1f} | {:.1f} |\n", n, name, m.wall_s, m.peak_mib,
                 m.peak_mib * 1048576.0 / static_cast<double>(n));
      if (m.code != 0) fmt::print("  exit {}: {}\n", m.code, m.out.substr(0, 400));
      if (args[0] == "/usr/bin/python3") fmt::print("  {}\n", m.out);
    }
  }
  return 0;
}
