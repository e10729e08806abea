#include "samples.h"

#include <fmt/format.h>

#include <cmath>
#include <limits>
#include <ostream>
#include <span>
#include <vector>

#include "gyrotherm/storage/database.h"
#include "output.h"

namespace gyrotherm::cli {

namespace {

// Shortest text that reads back as the same double; "" for NaN (a value
// the frame flagged invalid).
void append_value(std::string& line, double v) {
  line += ',';
  if (!std::isnan(v)) fmt::format_to(std::back_inserter(line), "{}", v);
}

}  // namespace

int cmd_samples(const SamplesArgs& args, std::ostream& out) {
  const double from_s = args.from_s.value_or(-std::numeric_limits<double>::infinity());
  const double to_s = args.to_s.value_or(std::numeric_limits<double>::infinity());
  if (std::isnan(from_s) || std::isnan(to_s) || !(from_s < to_s)) {
    return fail(fmt::format("samples: --from {} must be before --to {}", from_s, to_s), 2);
  }
  auto db = storage::Database::open_read_only(args.db_path);
  if (!db) return fail(db.error().message);
  if (auto run = db->run(args.run_id); !run) return fail(run.error().message);
  auto duts = db->run_duts(args.run_id);
  if (!duts) return fail(duts.error().message);
  if (duts->empty()) {
    return fail(
        fmt::format("samples: {}: run {} has no DUT (no samples)", args.db_path, args.run_id));
  }
  const storage::RunDutRecord* dut = nullptr;
  std::vector<std::string> serials;
  for (const storage::RunDutRecord& d : *duts) {
    if (!dut && (args.dut_serial.empty() || d.dut.serial == args.dut_serial)) dut = &d;
    serials.push_back(fmt::format("'{}'", d.dut.serial));
  }
  if (!dut) {
    return fail(fmt::format("samples: {}: run {} has no DUT '{}' (its DUTs: {})", args.db_path,
                            args.run_id, args.dut_serial, fmt::join(serials, ", ")));
  }
  std::vector<const storage::ChannelRecord*> channels;
  std::vector<std::string> names;
  for (const storage::ChannelRecord& c : dut->channels) {
    if (args.channel.empty() || c.spec.name == args.channel) channels.push_back(&c);
    names.push_back(c.spec.name);
  }
  if (channels.empty()) {
    return fail(fmt::format(
        "samples: {}: DUT '{}' of run {} has no channel '{}' (its channels: {})", args.db_path,
        dut->dut.serial, args.run_id, args.channel, fmt::join(names, ", ")));
  }

  std::string line = "t_s";
  for (const storage::ChannelRecord* c : channels) {
    line += ',';
    line +=
        c->spec.unit.empty() ? c->spec.name : fmt::format("{} ({})", c->spec.name, c->spec.unit);
  }
  out << line << '\n';

  // The DUT's channels come from the same frames, so their chunks share
  // clocks: stream the first channel chunk by chunk and read the others
  // over each block's span (memory: one chunk per channel).
  std::vector<std::vector<double>> others(channels.size());
  std::vector<std::vector<double>> other_t(channels.size());
  Status inner = Status::Ok();
  Status s = db->for_each_channel_block(
      channels[0]->id, from_s, to_s,
      [&](std::span<const double> t, std::span<const double> v, std::span<const uint32_t>) {
        const double span_to_s = std::nextafter(t.back(), std::numeric_limits<double>::infinity());
        for (std::size_t k = 1; k < channels.size(); ++k) {
          others[k].clear();
          other_t[k].clear();
          inner = db->for_each_channel_block(
              channels[k]->id, t.front(), span_to_s,
              [&](std::span<const double> tk, std::span<const double> vk,
                  std::span<const uint32_t>) {
                other_t[k].insert(other_t[k].end(), tk.begin(), tk.end());
                others[k].insert(others[k].end(), vk.begin(), vk.end());
                return true;
              });
          if (!inner) return false;
        }
        std::vector<std::size_t> at(channels.size(), 0);
        for (std::size_t i = 0; i < t.size(); ++i) {
          line.clear();
          fmt::format_to(std::back_inserter(line), "{}", t[i]);
          append_value(line, v[i]);
          for (std::size_t k = 1; k < channels.size(); ++k) {
            // Same frame: same time up to the rounding of the implicit clock.
            std::size_t& j = at[k];
            while (j < other_t[k].size() && other_t[k][j] < t[i] - 1e-9) ++j;
            const bool found = j < other_t[k].size() && std::abs(other_t[k][j] - t[i]) <= 1e-9;
            append_value(line, found ? others[k][j] : std::numeric_limits<double>::quiet_NaN());
          }
          line += '\n';
          out << line;
        }
        return static_cast<bool>(out);
      });
  if (!s) return fail(s.error().message);
  if (!inner) return fail(inner.error().message);
  out.flush();
  if (!out) return fail("samples: writing the CSV failed");
  return 0;
}

}  // namespace gyrotherm::cli
