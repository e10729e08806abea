#include "dut_acquisition.h"

#include <fmt/format.h>
#include <spdlog/spdlog.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <nlohmann/json.hpp>

#include "gyrotherm/config/run_config.h"
#include "gyrotherm/drivers/kvh1750.h"

namespace gyrotherm::station {

std::string dut_name(const config::DutSection& dut) {
  return dut.serial.empty() ? std::string("(no serial)") : dut.serial;
}

DutAcquisition::DutAcquisition(const config::StationConfig& config,
                               std::vector<std::unique_ptr<drivers::DutSource>> sources,
                               std::vector<std::unique_ptr<drivers::ShellProbes>> probes,
                               Links links)
    : config_(config), links_(std::move(links)) {
  for (std::size_t i = 0; i < sources.size(); ++i) {
    auto live = std::make_unique<DutLive>();
    live->index = i;
    live->cfg = &config_.duts[i];
    live->source = std::move(sources[i]);
    if (i < probes.size()) live->probes = std::move(probes[i]);
    const auto& channels = live->source->channels();
    for (std::size_t c = 0; c < channels.size(); ++c) {
      if (channels[c].kind == ChannelKind::kRate && !channels[c].axis.empty()) {
        live->rate_channels.push_back(c);
      }
      if (channels[c].kind == ChannelKind::kTemperature && live->temp_channel < 0) {
        live->temp_channel = static_cast<int>(c);
      }
      if (channels[c].axis == live->cfg->primary_axis && channels[c].kind == ChannelKind::kRate) {
        live->primary_channel = static_cast<int>(c);
      }
    }
    live->window_sum.assign(live->rate_channels.size(), 0.0);
    live->window_n.assign(live->rate_channels.size(), 0);
    live->rates_dph.assign(live->rate_channels.size(), std::nullopt);
    live->bin_mean_dph.resize(live->rate_channels.size());
    live->bin_sum.assign(live->rate_channels.size(), 0.0);
    live->bin_n.assign(live->rate_channels.size(), 0);
    duts_.push_back(std::move(live));
  }
  for (const auto& d : duts_) publish_dut_status(*d);
}

void DutAcquisition::prepare(double now_s, double wall_s) {
  for (auto& d : duts_) {
    d->last_s.store(now_s);
    d->last_wall_s.store(wall_s);
    if (d->probes) {
      if (auto st = d->probes->connect(); !st) {
        spdlog::warn("DUT {} probes: {} (will keep retrying)", dut_name(*d->cfg),
                     st.error().message);
      }
    }
  }
}

void DutAcquisition::start_sources() {
  for (auto& d : duts_) {
    DutLive* live = d.get();
    live->source->start([this, live](std::span<const DutFrame> f) { on_dut_frames(*live, f); });
  }
}

void DutAcquisition::stop_sources() {
  for (auto& d : duts_) d->source->stop();
}

void DutAcquisition::read_silence(
    schedules::Readings& r,
    const std::function<double(double since_s, double since_wall_s)>& silent) {
  // The most silent required DUT speaks for the gyro_lost interlock (whose
  // timeout is the smallest of the DUTs' silent_timeout_s), and its message
  // names every required DUT silent past its own timeout. A DUT that is not
  // required is marked lost instead, and the run goes on without it.
  r.gyro_heard = true;
  std::vector<std::string> silent_duts;
  for (const auto& d : duts_) {
    if (!d->in_run.load()) continue;  // not recorded in this run
    const double silent_s = silent(d->last_s.load(), d->last_wall_s.load());
    if (!d->cfg->required) {
      const bool lost = silent_s > d->cfg->silent_timeout_s;
      if (lost != d->lost.exchange(lost)) {
        const std::string message =
            lost ? fmt::format(
                       "DUT {} lost: no frame for {:.1f} s (silent_timeout_s {:g}); it is "
                       "not required: its acquisition ends here and the run goes on "
                       "with the other DUTs",
                       dut_name(*d->cfg), silent_s, d->cfg->silent_timeout_s)
                 : fmt::format("DUT {} back: frames again; its acquisition goes on",
                               dut_name(*d->cfg));
        if (lost) {
          spdlog::warn("{}", message);
        } else {
          spdlog::info("{}", message);
        }
        links_.post_event("dut", message);
      }
      continue;
    }
    if (silent_s > d->cfg->silent_timeout_s) silent_duts.push_back(dut_name(*d->cfg));
    if (silent_s > r.gyro_silent_s) {
      r.gyro_silent_s = silent_s;
      if (duts_.size() > 1) r.gyro_stream = fmt::format("DUT {} stream", dut_name(*d->cfg));
    }
    r.gyro_heard = r.gyro_heard && d->heard.load();
  }
  if (silent_duts.size() > 1) {
    std::string names;
    for (const auto& n : silent_duts) names += (names.empty() ? "" : ", ") + n;
    r.gyro_stream = fmt::format("DUT streams {}", names);
  }
}

void DutAcquisition::add_health(StatusSnapshot& s) const {
  s.gyro = duts_.front()->source->health();
  for (std::size_t i = 0; i < duts_.size() && i < s.duts.size(); ++i) {
    s.duts[i].health = duts_[i]->source->health();
  }
}

void DutAcquisition::forget_coverage_before(double t_s) {
  for (auto& d : duts_) {
    {
      std::lock_guard lock(d->coverage_mu);
      if (d->coverage) d->coverage->forget_before(t_s);
    }
    std::lock_guard lock(d->bins_mu);
    const auto keep = std::lower_bound(d->bin_t_s.begin(), d->bin_t_s.end(), std::floor(t_s));
    const auto drop = keep - d->bin_t_s.begin();
    d->bin_t_s.erase(d->bin_t_s.begin(), keep);
    for (auto& axis : d->bin_mean_dph) axis.erase(axis.begin(), axis.begin() + drop);
  }
}

void DutAcquisition::bin_seconds(DutLive& dut, int64_t run_id, std::span<const DutFrame> rel) {
  const auto& channels = dut.source->channels();
  std::lock_guard lock(dut.bins_mu);
  if (dut.bins_run_id != run_id) {
    dut.bins_run_id = run_id;
    dut.bin_t_s.clear();
    for (auto& axis : dut.bin_mean_dph) axis.clear();
    dut.bin_open_s = -1;
  }
  auto close_open_second = [&] {
    if (dut.bin_open_s < 0) return;
    dut.bin_t_s.push_back(dut.bin_open_s);
    for (std::size_t a = 0; a < dut.rate_channels.size(); ++a) {
      dut.bin_mean_dph[a].push_back(dut.bin_n[a] > 0
                                        ? dut.bin_sum[a] / static_cast<double>(dut.bin_n[a])
                                        : std::numeric_limits<double>::quiet_NaN());
      dut.bin_sum[a] = 0;
      dut.bin_n[a] = 0;
    }
  };
  for (const auto& f : rel) {
    const double second_s = std::floor(f.t_s);
    if (second_s < dut.bin_open_s) continue;  // out of order: its second is closed
    if (second_s > dut.bin_open_s) {
      close_open_second();
      dut.bin_open_s = second_s;
    }
    for (std::size_t a = 0; a < dut.rate_channels.size(); ++a) {
      const std::size_t c = dut.rate_channels[a];
      const double v = f.raw[c] * channels[c].scale;
      if (!std::isfinite(v)) continue;
      dut.bin_sum[a] += v;
      ++dut.bin_n[a];
    }
  }
}

std::vector<DutAcquisition::AxisSeconds> DutAcquisition::gated_seconds(
    std::span<const std::pair<double, double>> windows) {
  const int64_t run_id = links_.run_clock.load().run_id;
  std::vector<AxisSeconds> out;
  for (auto& d : duts_) {
    if (!d->in_run.load() || !d->cfg->required || d->lost.load()) continue;
    const auto& channels = d->source->channels();
    std::lock_guard lock(d->bins_mu);
    if (d->bins_run_id != run_id) continue;
    for (std::size_t a = 0; a < d->rate_channels.size(); ++a) {
      AxisSeconds axis{fmt::format("{} {}", dut_name(*d->cfg), channels[d->rate_channels[a]].axis),
                       {}};
      for (const auto& [from_s, to_s] : windows) {
        // The seconds wholly inside the window.
        auto it = std::lower_bound(d->bin_t_s.begin(), d->bin_t_s.end(), std::ceil(from_s));
        for (; it != d->bin_t_s.end() && *it + 1.0 <= to_s; ++it) {
          const double v = d->bin_mean_dph[a][static_cast<std::size_t>(it - d->bin_t_s.begin())];
          if (std::isfinite(v)) axis.rate_dph.push_back(v);
        }
      }
      out.push_back(std::move(axis));
    }
  }
  return out;
}

void DutAcquisition::on_dut_frames(DutLive& dut, std::span<const DutFrame> frames) {
  dut.last_s.store(links_.clock.now_s());
  dut.last_wall_s.store(links_.wall.monotonic_s());
  dut.heard.store(true);
  // One read of the pair: the batch is timed from the start of the run it
  // is stored under, and handed to the writer before that run can end.
  links_.run_clock.with_samples_run([&](const RunClock::Value& run) {
    if (run.run_id == 0 || frames.empty()) return;
    std::shared_ptr<const storage::RunDutRecord> layout;
    {
      std::lock_guard lock(dut.layout_mu);
      layout = dut.layout;
    }
    // Registered before the run's clock was published; a mismatch means the
    // registration failed (logged there): the frames cannot be stored.
    if (!layout || layout->run_id != run.run_id) return;
    thread_local std::vector<DutFrame> rel;
    rel.assign(frames.begin(), frames.end());
    for (auto& f : rel) f.t_s -= run.t0_s;
    links_.writer.push_frames(*layout, rel);
    {
      std::lock_guard lock(dut.coverage_mu);
      if (!dut.coverage || dut.coverage_run_id != run.run_id) {
        dut.coverage.emplace(1.0 / dut.cfg->link.rate_hz);
        dut.coverage_run_id = run.run_id;
      }
      for (const auto& f : rel) dut.coverage->add(f.t_s);
    }
    bin_seconds(dut, run.run_id, rel);
    {
      std::lock_guard handed(handed_mu_);
      dut.handed_run_id = run.run_id;
      dut.handed_until_s = rel.back().t_s;
    }
    handed_cv_.notify_all();
  });
  const auto& channels = dut.source->channels();
  std::lock_guard lock(links_.status_mu);
  for (const auto& f : frames) {
    if (dut.window_start_s < 0 || f.t_s < dut.window_start_s) {
      dut.window_start_s = std::floor(f.t_s);
      std::fill(dut.window_sum.begin(), dut.window_sum.end(), 0.0);
      std::fill(dut.window_n.begin(), dut.window_n.end(), 0);
      dut.window_frames = 0;
    }
    if (f.t_s >= dut.window_start_s + 1.0) {
      if (dut.window_frames > 0) {
        for (std::size_t a = 0; a < dut.rate_channels.size(); ++a) {
          dut.rates_dph[a] =
              dut.window_n[a] > 0
                  ? std::optional(dut.window_sum[a] / static_cast<double>(dut.window_n[a]))
                  : std::nullopt;
        }
        dut.samples_per_s = static_cast<double>(dut.window_frames);
      }
      dut.window_start_s = std::floor(f.t_s);
      std::fill(dut.window_sum.begin(), dut.window_sum.end(), 0.0);
      std::fill(dut.window_n.begin(), dut.window_n.end(), 0);
      dut.window_frames = 0;
    }
    for (std::size_t a = 0; a < dut.rate_channels.size(); ++a) {
      const std::size_t c = dut.rate_channels[a];
      const double v = f.raw[c] * channels[c].scale;
      if (!std::isfinite(v)) continue;
      dut.window_sum[a] += v;
      ++dut.window_n[a];
    }
    ++dut.window_frames;
    if (dut.temp_channel >= 0) {
      const double t = f.raw[static_cast<std::size_t>(dut.temp_channel)] *
                       channels[static_cast<std::size_t>(dut.temp_channel)].scale;
      if (std::isfinite(t)) dut.temp_c = t;
    }
  }
  publish_dut_status(dut);
}

// DUT `dut`'s live figures into the snapshot (links_.status_mu held).
void DutAcquisition::publish_dut_status(const DutLive& dut) {
  if (links_.snapshot.duts.size() != duts_.size()) links_.snapshot.duts.resize(duts_.size());
  DutStatus& st = links_.snapshot.duts[dut.index];
  st.serial = dut.cfg->serial;
  st.model = dut.cfg->model;
  st.primary_axis = dut.cfg->primary_axis;
  const auto& channels = dut.source->channels();
  st.rates_dph.clear();
  for (std::size_t a = 0; a < dut.rate_channels.size(); ++a) {
    st.rates_dph.emplace_back(channels[dut.rate_channels[a]].axis, dut.rates_dph[a]);
  }
  st.temp_c = dut.temp_c;
  st.samples_per_s = dut.samples_per_s;
  st.required = dut.cfg->required;
  st.lost = dut.lost.load();
  if (dut.index == 0) {
    // The first DUT's primary axis is "the gyro" of the older status fields.
    for (std::size_t a = 0; a < dut.rate_channels.size(); ++a) {
      if (static_cast<int>(dut.rate_channels[a]) == dut.primary_channel) {
        links_.snapshot.gyro_rate_dph = dut.rates_dph[a];
      }
    }
    links_.snapshot.gyro_samples_per_s = dut.samples_per_s;
  }
}

void DutAcquisition::register_run_duts(storage::Database& db, int64_t run_id,
                                       const std::vector<std::string>& serials) {
  for (auto& d : duts_) {
    const config::DutSection& cfg = *d->cfg;
    const bool named =
        serials.empty() || std::find(serials.begin(), serials.end(), cfg.serial) != serials.end();
    d->in_run.store(named);
    if (!named) {
      // Not asked for: its frames are not stored under this run.
      std::lock_guard lock(d->layout_mu);
      d->layout.reset();
      d->probe_layout.reset();
      continue;
    }
    storage::RunDutRecord rec;
    rec.run_id = run_id;
    rec.position = static_cast<int>(d->index);
    rec.dut.serial = cfg.serial;
    rec.dut.model = cfg.model;
    rec.config_json = config::dut_config_json(cfg).dump();  // what the run analysis reads
    rec.primary_axis = cfg.primary_axis;
    rec.axes = cfg.axes;
    rec.rate_hz = cfg.link.rate_hz;
    rec.seq_modulo = cfg.link.protocol == "kvh1750"
                         ? drivers::kKvh1750SeqModulo
                         : (cfg.link.ascii.seq_column ? cfg.link.ascii.seq_modulo : 0);
    const auto& channels = d->source->channels();
    for (std::size_t c = 0; c < channels.size(); ++c) {
      rec.channels.push_back({0, run_id, 0, static_cast<int>(c), channels[c]});
    }
    if (d->probes) {
      const int n = static_cast<int>(channels.size());
      rec.channels.push_back(
          {0, run_id, 0, n, {"probe_top_c", "degC", ChannelKind::kTemperature, "", 1.0}});
      rec.channels.push_back(
          {0, run_id, 0, n + 1, {"probe_side_c", "degC", ChannelKind::kTemperature, "", 1.0}});
    }
    auto added = db.add_run_dut(run_id, rec);
    std::lock_guard lock(d->layout_mu);
    if (!added) {
      // Its frames cannot be stored under this run (on_dut_frames drops
      // them): said in the run's events.
      d->layout.reset();
      d->probe_layout.reset();
      links_.add_event(
          "error",
          fmt::format("DUT {}: not registered in run {} ({}); its samples are not recorded",
                      dut_name(cfg), run_id, added.error().message));
      continue;
    }
    auto frames = std::make_shared<storage::RunDutRecord>(*added);
    auto probes = std::make_shared<storage::RunDutRecord>(*added);
    const std::size_t n = channels.size();
    frames->channels.resize(std::min(n, frames->channels.size()));
    probes->rate_hz = 1.0 / config_.control.tick_s;  // read once a control tick
    probes->seq_modulo = 0;
    probes->channels.erase(probes->channels.begin(),
                           probes->channels.begin() +
                               static_cast<std::ptrdiff_t>(std::min(n, probes->channels.size())));
    d->layout = std::move(frames);
    d->probe_layout =
        d->probes ? std::shared_ptr<const storage::RunDutRecord>(std::move(probes)) : nullptr;
  }
}

// Each DUT's own probes, once a control tick, into its probe channels (the
// frame's raw[] at those channels' indices).
std::vector<std::string> DutAcquisition::read_dut_probes(double now_s) {
  std::vector<std::string> events;
  for (auto& d : duts_) {
    if (!d->probes) continue;
    auto top = d->probes->top_c();
    auto side = top ? d->probes->side_c() : Result<double>(top.error());
    if (!top || !side) {
      if (!d->probes_failing) {
        d->probes_failing = true;
        events.push_back(
            fmt::format("DUT {} probes: no answer ({}); its own shell temperatures "
                        "are missing from now",
                        dut_name(*d->cfg), (!top ? top.error() : side.error()).message));
      }
      continue;
    }
    if (d->probes_failing) {
      d->probes_failing = false;
      events.push_back(fmt::format("DUT {} probes: answer again", dut_name(*d->cfg)));
    }
    std::shared_ptr<const storage::RunDutRecord> layout;
    {
      std::lock_guard lock(d->layout_mu);
      layout = d->probe_layout;
    }
    const RunClock::Value run = links_.run_clock.load();
    if (!layout || run.run_id == 0 || layout->run_id != run.run_id || layout->channels.size() < 2) {
      continue;
    }
    DutFrame f;
    f.t_s = now_s - run.t0_s;
    f.raw[static_cast<std::size_t>(layout->channels[0].index)] = *top;
    f.raw[static_cast<std::size_t>(layout->channels[1].index)] = *side;
    links_.writer.push_frames(*layout, std::span(&f, 1));
  }
  return events;
}

bool DutAcquisition::await_gyro(int64_t run_id, double until_s,
                                std::chrono::milliseconds max_wait) {
  std::unique_lock lock(handed_mu_);
  return handed_cv_.wait_for(lock, max_wait, [&] {
    return std::all_of(duts_.begin(), duts_.end(), [&](const auto& d) {
      return d->handed_run_id == run_id && d->handed_until_s >= until_s;
    });
  });
}

double DutAcquisition::data_covered_s(double from_s, double to_s) {
  const int64_t run_id = links_.run_clock.load().run_id;
  double least = std::numeric_limits<double>::infinity();
  for (auto& d : duts_) {
    if (d->lost.load() || !d->in_run.load()) continue;
    std::lock_guard lock(d->coverage_mu);
    const double covered =
        d->coverage && d->coverage_run_id == run_id ? d->coverage->covered_s(from_s, to_s) : 0.0;
    least = std::min(least, covered);
  }
  return std::isinf(least) ? std::max(0.0, to_s - from_s) : least;
}

std::optional<double> DutAcquisition::data_reached_at_s(double from_s, double need_s) {
  const int64_t run_id = links_.run_clock.load().run_id;
  double latest = from_s + need_s;  // no DUT: the clock's
  for (auto& d : duts_) {
    if (d->lost.load() || !d->in_run.load()) continue;
    std::lock_guard lock(d->coverage_mu);
    if (!d->coverage || d->coverage_run_id != run_id) return std::nullopt;
    const auto at = d->coverage->reached_at(from_s, need_s);
    if (!at) return std::nullopt;
    latest = std::max(latest, *at);
  }
  return latest;
}

void DutAcquisition::seed_coverage(storage::Database& db, int64_t run_id, double from_s) {
  for (auto& d : duts_) {
    std::shared_ptr<const storage::RunDutRecord> layout;
    {
      std::lock_guard lock(d->layout_mu);
      layout = d->layout;
    }
    schedules::CoverageSpans coverage(1.0 / d->cfg->link.rate_hz);
    if (layout && layout->run_id == run_id && !layout->channels.empty()) {
      const Status st = db.for_each_channel_block(
          layout->channels.front().id, from_s, std::numeric_limits<double>::infinity(),
          [&](std::span<const double> t_s, std::span<const double>, std::span<const uint32_t>) {
            for (double t : t_s) coverage.add(t);
            return true;
          });
      if (!st) {
        spdlog::error(
            "run {}: DUT {}: stored samples not read back ({}); its coverage starts "
            "anew",
            run_id, dut_name(*d->cfg), st.error().message);
        coverage = schedules::CoverageSpans(1.0 / d->cfg->link.rate_hz);
      }
    }
    std::lock_guard lock(d->coverage_mu);
    d->coverage = std::move(coverage);
    d->coverage_run_id = run_id;
  }
}

}  // namespace gyrotherm::station
