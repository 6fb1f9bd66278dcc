// pmsm-thermal monitor: what a person watching the bus wants to see, per axis: winding
// temperature +- sigma, magnet temperature, Rs, drive state, faults, current limit,
// time-to-limit and whether the estimate is stale; with the plant's truth frames beside it
// when a bench publishes them, and the error. Reads the bus itself (IFACE) or a candump log
// (--log FILE, '-' for stdin), decodes with the project's codec (CRC and alive counter of
// commands checked: rejected frames are counted and shown, and so are the daemon's own
// rejections from RECEIVE_STATUS), and shows a line per axis every --every seconds of drive
// time: redrawn in place on a terminal, appended otherwise (logs, pipes, --log). Events
// (faults, rejections) are printed above the block. A summary ends it, with the loop timing
// of LOOP_TIMING. With --check-* it is the HIL
// tests' judge: exit 1 when the estimates stray further from the truth than allowed.
#include <cerrno>
#include <cstring>
#include <unistd.h>

#include <array>
#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <iostream>
#include <map>
#include <optional>
#include <stdexcept>
#include <string>

#include <fmt/format.h>

#include "cli_validators.hpp"
#include "text_file.hpp"
#include "commands.hpp"
#include "text_input.hpp"
#include "pmsm/hal/codec.hpp"
#include "pmsm/hal/rt.hpp"
#include "pmsm/hal/signals.hpp"
#include "pmsm/hal/socketcan.hpp"
#include "pmsm/tools/candump.hpp"

namespace pmsm::app {
namespace {

namespace protocol = hal::protocol;
namespace candump = hal::candump;

struct MonitorOptions {
  std::string iface;
  std::string log;
  std::optional<int> node;
  double every_s = 1.0;
  double threshold_C = 40.0;
  std::optional<double> check_rms_C;
  std::optional<double> check_max_C;
  std::size_t min_estimates = 0;
  std::optional<double> duration_s;
  std::string csv;  // one row per THERMAL_ESTIMATE: time, node, estimate, sigma, truth
  bool plain = false;     // --plain: never redraw in place
  bool in_place = false;  // redraw the axis block (a live bus on a terminal)
};

const char* label(std::span<const protocol::ValueLabel> labels, std::int64_t value) {
  return protocol::label_of(labels, value).data();  // the tables' labels are string literals
}

struct Axis {
  std::optional<protocol::ThermalEstimate> thermal;
  std::optional<protocol::ResistanceEstimate> rs;
  std::optional<protocol::DriveStatus> status;
  std::optional<double> truth_C;
  // The last estimate compared with the truth at its own time (judge()): the error a line shows.
  // An estimate that waits for the next truth frame (pending) is not compared with the last one,
  // which is older than it (the line after a plant stopped showed such an error, -5.3 C, that the
  // summary rightly left out).
  struct Compared {
    double estimate_C = 0.0;
    double truth_C = 0.0;
  };
  std::optional<Compared> compared;
  // HEARTBEATs since the last TRUTH_THERMAL, the most seen between two truths while the plant
  // reported, and the daemon's uptime at the last truth (its last HEARTBEAT's). More HEARTBEATs
  // than ever came between two truths, and at least two: the plant has stopped reporting while
  // the daemon runs on, and its last truth is no measure of the estimates that follow.
  std::uint32_t heartbeats_since_truth = 0, most_heartbeats_between_truths = 0;
  std::optional<double> uptime_at_truth_s;
  [[nodiscard]] bool truth_stale() const {
    return truth_C && heartbeats_since_truth >= 2 && heartbeats_since_truth > most_heartbeats_between_truths;
  }
  std::optional<double> time_s;       // plant's simulated time, else the daemon's uptime
  bool plant_time = false;            // time_s comes from PLANT_STATUS
  double next_print_s = 0.0;
  std::uint32_t active_faults = 0;
  std::uint32_t known_faults = 0;     // faults whose state a FAULT frame has told
  std::uint64_t fault_reports = 0;
  std::uint64_t injections = 0, injections_accepted = 0;
  std::optional<protocol::ReceiveStatus> receive;  // the daemon's own rejections
  // RECEIVE_STATUS's counts since the daemon started, modulo 256, unwrapped from one frame to
  // the next (it comes every second, commands at most a few hundred a second): exact when this
  // monitor listened from the daemon's start, short by multiples of 256 otherwise.
  std::uint64_t accepted_seen = 0, rejected_seen = 0;
  // The daemon's uptime in its last HEARTBEAT: when it falls, the daemon started again, and its
  // counts with it (the next RECEIVE_STATUS counts from zero, not from the last one).
  std::optional<double> daemon_uptime_s;
  // HEARTBEAT's AmbientSource: shown when the thermal model's boundary is not a sensor's reading.
  std::optional<protocol::AmbientSource> ambient_source;
  // The RECEIVE_STATUS frames since the last HEARTBEAT, with their time (when the frames have
  // one) and the totals before each: a restarted daemon may report before its first HEARTBEAT
  // tells the restart, and those reports, read as a wrap of the old daemon's counts, are undone
  // when it does; the old daemon's last reports stay.
  struct Report {
    std::optional<double> time_s;
    std::uint64_t accepted_before, rejected_before;
  };
  std::array<Report, 16> reports{};
  std::size_t report_count = 0;
  std::optional<protocol::LoopTiming> timing;
  double worst_latency_us = 0.0;
  std::uint64_t timing_windows = 0;
  // Windows whose LatencyMax or DeadlineMisses stood at the signal's top: the figures are then
  // lower bounds, and the summary says "at least".
  bool latency_saturated = false;
  // Deadline misses per daemon run: the LOOP_TIMING windows' sum (a window's count saturates at
  // 255) and HEARTBEAT's count since the daemon started (saturates at 65535), the larger of the
  // two counting; the runs before a restart, summed.
  std::uint64_t window_misses = 0, heartbeat_misses = 0, earlier_misses = 0;
  bool window_misses_saturated = false, earlier_misses_saturated = false, earlier_since_start = false;
  struct Misses {
    std::uint64_t count;
    bool saturated;    // a lower bound
    bool since_start;  // HEARTBEAT's: since the daemon started, windows this monitor saw or not
  };
  [[nodiscard]] Misses run_misses() const {
    const bool heartbeat = heartbeat_misses > window_misses;
    return {heartbeat ? heartbeat_misses : window_misses,
            heartbeat ? static_cast<double>(heartbeat_misses) >= protocol::heartbeat::kDeadlineMisses.maximum
                      : window_misses_saturated,
            heartbeat};
  }
  // The commands this monitor has seen, per stream: alive counter checked as the daemon does.
  std::array<protocol::AliveCounterCheck, protocol::kMessageCount> counters;
  // Error statistics of calibrated estimates where the truth is above the threshold.
  std::size_t n = 0;
  double sq = 0.0, sum = 0.0, max = 0.0;
  // Time alignment (when the log has the SENSOR_SAMPLEs): an estimate belongs to the last
  // sample before it, a truth frame to the sample after which the plant sent it; an estimate
  // is compared with the truth interpolated at its own sample, once the next truth frame is
  // in. Without samples it is compared with the latest truth, up to one truth period stale.
  std::optional<std::uint32_t> sample_seq;
  std::optional<std::pair<std::uint32_t, double>> truth_at;  // (sample, truth) of the last truth frame
  struct Pending {
    std::uint32_t seq;
    double time_s;
    protocol::ThermalEstimate estimate;
  };
  std::vector<Pending> pending;
  std::uint64_t not_compared = 0;  // estimates no truth frame followed (the end of the log, a plant gone)
};

constexpr std::uint64_t kMaxListedBadLines = 10;

class Monitor {
 public:
  explicit Monitor(const MonitorOptions& o) : o_(o) {
    if (!o.csv.empty()) {
      errno = 0;
      csv_.open(o.csv);
      if (!csv_) {
        throw std::runtime_error("cannot write " + o.csv + (errno != 0 ? std::string(" (") + std::strerror(errno) + ")" : ""));
      }
      csv_ << "time_s,node,winding_est_C,winding_sigma_C,winding_true_C,calibrated\n";
    }
  }

  // Frames the kernel dropped for this monitor's own socket (its receive queue full), as the
  // socket counts them: an alive-counter jump after such a drop is this monitor's loss, not
  // the bus's, and is reported so.
  void on_own_drops(std::uint64_t total) {
    if (total > own_drops_) {
      event(fmt::format("monitor: this monitor's socket dropped {} frame(s) (its receive queue was full; {} so far): "
                        "the frames were on the bus, and the daemon's own count is RECEIVE_STATUS's",
                        total - own_drops_, total));
      own_drops_ = total;
      own_drops_unexplained_ = true;
    }
  }

  // The live socket found the interface down (ENETDOWN, or gone), and later back. A drive on it
  // cannot publish INTERFACE_DOWN while it is down: it sends the fault once the bus is back,
  // often already cleared, so this monitor says what it saw itself.
  void on_interface(const std::string& iface, bool up) {
    if (!up && !interface_down_) {
      ++interface_losses_;
      event(fmt::format("monitor: {} is down (this monitor's own socket): no frame can cross it until it is back; "
                        "a drive on it reports INTERFACE_DOWN once it can send again",
                        iface));
    } else if (up && interface_down_) {
      event(fmt::format("monitor: {} is back up: socket reopened", iface));
    }
    interface_down_ = !up;
  }

  // time_s: when the frame was received or logged (seconds on any clock that does not go back),
  // when known. Times that go back (a -td log: gaps, not times) are not used at all.
  void on_frame(const hal::CanFrame& frame, std::optional<double> time_s = std::nullopt) {
    ++frames_;
    if (time_s && last_time_s_ && *time_s < *last_time_s_) {
      times_usable_ = false;
    }
    last_time_s_ = time_s;
    const std::optional<double> frame_time_s = times_usable_ ? time_s : std::nullopt;
    protocol::AnyDecoded d;
    protocol::DecodeStatus status = protocol::decode_any(frame, d);
    // A command whose CRC held but whose value is out of range is genuine: it advances its
    // stream's alive counter, as it does the daemon's (decode_any).
    const bool identified = status == protocol::DecodeStatus::kOk ||
                            (status == protocol::DecodeStatus::kOutOfRange && protocol::message_def(d.type).e2e);
    if (identified && o_.node && d.node != *o_.node) {
      return;  // another axis: not even its alive counters (the summary covers this node alone)
    }
    if (identified && protocol::message_def(d.type).e2e) {
      const protocol::DecodeStatus counter = axes_[d.node].counters[static_cast<std::size_t>(d.type)].check(d.alive_counter);
      if (counter != protocol::DecodeStatus::kOk) {
        status = counter;  // the daemon checks the counter first, the range after it
      }
    }
    if (status != protocol::DecodeStatus::kOk) {
      ++rejected_[static_cast<std::size_t>(status)];
      if (status != protocol::DecodeStatus::kUnknownId) {
        // This monitor's own check of what it received (it may miss frames the daemon gets):
        // the daemon's rejections are RECEIVE_STATUS's, reported as "the daemon rejected".
        if (status == protocol::DecodeStatus::kCounterJump && own_drops_unexplained_) {
          event(fmt::format("monitor: frame 0x{:03X}: alive-counter jump after this monitor's own socket dropped frames "
                            "(not a loss on the bus)",
                            frame.id));
        } else {
          event(fmt::format("monitor: frame 0x{:03X} fails this monitor's check: {} ({})", frame.id,
                            protocol::to_string(status), protocol::describe(status)));
        }
      }
      return;
    }
    if (protocol::message_def(d.type).e2e) {
      own_drops_unexplained_ = false;  // a stream in step again: later jumps are not the drop's
    }
    Axis& a = axes_[d.node];
    if (const auto* t = std::get_if<protocol::ThermalEstimate>(&d.message)) {
      a.thermal = *t;
      if (a.sample_seq && a.truth_at) {
        if (!a.pending.empty() && a.pending.back().seq == *a.sample_seq) {
          a.pending.back() = {*a.sample_seq, a.time_s.value_or(0.0), *t};  // no sample since: the newer one stands
        } else if (a.pending.size() < 64) {
          a.pending.push_back({*a.sample_seq, a.time_s.value_or(0.0), *t});  // judged at the next truth frame
        } else {
          ++a.not_compared;  // no truth frame for 64 samples that carried estimates: the plant is gone
        }
      } else if (a.truth_stale()) {
        ++a.not_compared;  // the plant stopped reporting: no truth for it
      } else {
        judge(d.node, a, *t, a.time_s.value_or(0.0), a.truth_C);
      }
      maybe_print(d.node, a);
    } else if (const auto* sample = std::get_if<hal::SensorSample>(&d.message)) {
      a.sample_seq = sample->sequence;
    } else if (const auto* r = std::get_if<protocol::ResistanceEstimate>(&d.message)) {
      a.rs = *r;
    } else if (const auto* s = std::get_if<protocol::DriveStatus>(&d.message)) {
      a.status = *s;
    } else if (const auto* rs = std::get_if<protocol::ReceiveStatus>(&d.message)) {
      if (a.report_count < a.reports.size()) {
        a.reports[a.report_count++] = {frame_time_s, a.accepted_seen, a.rejected_seen};
      }
      if (a.receive && rejections(*rs) != rejections(*a.receive)) {
        event(fmt::format("node {}: the daemon rejected {} more frame(s); last 0x{:03X}: {}", d.node,
                          (rejections(*rs) - rejections(*a.receive)) & 0xFFU, rs->last_rejected_id,
                          label(protocol::kDecodeStatusLabels, rs->last_rejection)));
      }
      if (!a.receive) {
        a.accepted_seen = rs->commands_accepted;  // since the daemon started, modulo 256
        a.rejected_seen = rejections(*rs);
      } else {
        const auto delta = [](std::uint64_t now, std::uint64_t before) { return (now - before) & 0xFFU; };
        a.accepted_seen += delta(rs->commands_accepted, a.receive->commands_accepted);
        a.rejected_seen += delta(rs->rejected_crc, a.receive->rejected_crc) + delta(rs->rejected_counter, a.receive->rejected_counter) +
                           delta(rs->rejected_range, a.receive->rejected_range) +
                           delta(rs->rejected_format, a.receive->rejected_format) +
                           delta(rs->rejected_other, a.receive->rejected_other);
      }
      a.receive = *rs;
    } else if (const auto* lt = std::get_if<protocol::LoopTiming>(&d.message)) {
      // A window without a step (the power stage silent: its latencies read 0) has nothing to
      // show; the last window with steps stays the one the summary prints.
      if (lt->periods > 0U) {
        a.timing = *lt;
      }
      a.worst_latency_us = std::max(a.worst_latency_us, lt->latency_max_us);
      ++a.timing_windows;
      a.window_misses += lt->deadline_misses;
      a.latency_saturated = a.latency_saturated || lt->latency_max_us >= protocol::loop_timing::kLatencyMax.maximum;
      a.window_misses_saturated =
          a.window_misses_saturated || lt->deadline_misses >= protocol::loop_timing::kDeadlineMisses.maximum;
    } else if (const auto* h = std::get_if<protocol::Heartbeat>(&d.message)) {
      if (a.daemon_uptime_s && h->uptime_s < *a.daemon_uptime_s) {
        event(fmt::format("node {}: the daemon started again (uptime {:.1f} s after {:.1f} s)", d.node, h->uptime_s,
                          *a.daemon_uptime_s));
        // Its counts start from zero: reports that came after it started are undone (by the
        // frames' times; without times, all but the first since the last HEARTBEAT, which the
        // old daemon sent with it), and the next report counts from zero.
        const std::optional<double> started_s = frame_time_s ? std::optional<double>(*frame_time_s - h->uptime_s) : std::nullopt;
        for (std::size_t k = 0; k < a.report_count; ++k) {
          const Axis::Report& report = a.reports[k];
          const bool new_daemon = started_s && report.time_s ? *report.time_s >= *started_s - 0.05 : k >= 1;
          if (new_daemon) {
            a.accepted_seen = report.accepted_before;
            a.rejected_seen = report.rejected_before;
            break;
          }
        }
        if (a.receive) {
          a.receive = protocol::ReceiveStatus{};
        }
        const Axis::Misses run = a.run_misses();
        a.earlier_misses += run.count;
        a.earlier_misses_saturated = a.earlier_misses_saturated || run.saturated;
        a.earlier_since_start = a.earlier_since_start || run.since_start;
        a.window_misses = 0;
        a.heartbeat_misses = 0;
        a.window_misses_saturated = false;
      }
      a.daemon_uptime_s = h->uptime_s;
      a.ambient_source = h->ambient_source;
      ++a.heartbeats_since_truth;
      a.heartbeat_misses = h->deadline_misses;
      a.report_count = 0;  // the reports before a HEARTBEAT are its daemon's
      if (!a.plant_time) {
        set_time(a, h->uptime_s);
      }
    } else if (const auto* f = std::get_if<protocol::FaultReport>(&d.message)) {
      ++a.fault_reports;
      const std::uint32_t bit = 1U << static_cast<unsigned>(f->code);
      const bool was = (a.active_faults & bit) != 0U;
      const bool known = (a.known_faults & bit) != 0U;  // a log may start in the middle
      a.known_faults |= bit;
      if (f->active != was || !known) {
        event(fmt::format("node {}: fault {} {}", d.node, label(protocol::kFaultCodeLabels, static_cast<std::int64_t>(f->code)),
                          f->active ? "ACTIVE" : "cleared"));
      }
      a.active_faults = f->active ? (a.active_faults | bit) : (a.active_faults & ~bit);
    } else if (const auto* i = std::get_if<protocol::InjectionReport>(&d.message)) {
      ++a.injections;
      a.injections_accepted += i->result == protocol::InjectionResult::kAccepted ? 1U : 0U;
    } else if (const auto* tt = std::get_if<protocol::TruthThermal>(&d.message)) {
      if (a.truth_C) {  // (the HEARTBEATs before the plant's first report say nothing of its cadence)
        a.most_heartbeats_between_truths = std::max(a.most_heartbeats_between_truths, a.heartbeats_since_truth);
      }
      a.truth_C = tt->winding_temp_C;
      a.heartbeats_since_truth = 0;
      a.uptime_at_truth_s = a.daemon_uptime_s;
      if (a.sample_seq) {
        const std::pair<std::uint32_t, double> now{*a.sample_seq, tt->winding_temp_C};
        for (const Axis::Pending& p : a.pending) {
          std::optional<double> truth = now.second;
          if (a.truth_at && now.first != a.truth_at->first) {
            // Sequences are modulo 2^32: distances, not values, are compared.
            const double span = static_cast<double>(now.first - a.truth_at->first);
            const double into = static_cast<double>(p.seq - a.truth_at->first);
            if (into >= 0.0 && into <= span) {
              truth = a.truth_at->second + (now.second - a.truth_at->second) * into / span;
            }
          }
          judge(d.node, a, p.estimate, p.time_s, truth);
        }
        a.pending.clear();
        a.truth_at = now;
      }
    } else if (const auto* ps = std::get_if<protocol::PlantStatus>(&d.message)) {
      if (!a.plant_time && a.time_s) {
        event(fmt::format("node {}: a plant emulator is on the bus: its simulated time from here, not the daemon's uptime",
                          d.node));
      }
      a.plant_time = true;
      set_time(a, ps->simulated_time_s);
    }
  }

  // One estimate against the truth at its time: the CSV row and the error statistics.
  void judge(int node, Axis& a, const protocol::ThermalEstimate& t, double time_s, std::optional<double> truth) {
    if (t.valid && truth) {
      a.compared = Axis::Compared{t.winding_temp_C, *truth};
    }
    if (csv_.is_open() && t.valid) {
      csv_ << fmt::format("{:.3f},{},{:.2f},{:.2f},{},{}\n", time_s, node, t.winding_temp_C, t.winding_temp_sigma_C,
                          truth ? fmt::format("{:.2f}", *truth) : std::string{}, t.calibrated ? 1 : 0);
    }
    if (t.valid && t.calibrated && truth && *truth > o_.threshold_C) {
      const double err = t.winding_temp_C - *truth;
      a.sq += err * err;
      a.sum += err;
      a.max = std::max(a.max, std::abs(err));
      ++a.n;
    }
  }

  // Time runs on, or starts again (a new plant, a restarted daemon): then so do the lines.
  static void set_time(Axis& a, double t) {
    if (a.time_s && t < *a.time_s) {
      a.next_print_s = t;
      a.compared.reset();  // the run before's comparison is no measure of this one
    }
    a.time_s = t;
  }

  // The daemon's rejections in one RECEIVE_STATUS (each count modulo 256).
  static std::uint64_t rejections(const protocol::ReceiveStatus& r) {
    return r.rejected_crc + r.rejected_counter + r.rejected_range + r.rejected_format + r.rejected_other;
  }

  void maybe_print(int node, Axis& a) {
    const double t = a.time_s.value_or(0.0);
    if (t + 1e-9 < a.next_print_s) {
      return;
    }
    a.next_print_s = t + o_.every_s;
    if (o_.in_place) {
      redraw();
    } else {
      std::printf("%s\n", line(node, a).c_str());
    }
    std::fflush(stdout);
  }

  // A one-off line (a fault, a rejection): above the block on a terminal.
  void event(const std::string& text) {
    if (o_.in_place) {
      erase_block();
      std::printf("%s\n", text.c_str());
      redraw();
    } else {
      std::printf("%s\n", text.c_str());
    }
    std::fflush(stdout);
  }

  // The block of axis lines, drawn over the previous one (ANSI: cursor up, erase below).
  void redraw() {
    erase_block();
    for (const auto& [node, a] : axes_) {
      std::printf("%s\n", line(node, a).c_str());
    }
    block_lines_ = axes_.size();
  }
  void erase_block() {
    if (block_lines_ > 0U) {
      std::printf("\x1b[%zuF\x1b[J", block_lines_);
      block_lines_ = 0;
    }
  }

  [[nodiscard]] std::string line(int node, const Axis& a) const {
    // Which clock: the plant's simulated time once a PLANT_STATUS has come, else the daemon's
    // uptime (a real power stage sends no PLANT_STATUS).
    std::string out = fmt::format("node {:2d}  {} {:8.1f} s  ", node, a.plant_time ? "plant " : "uptime", a.time_s.value_or(0.0));
    if (a.thermal && a.thermal->valid) {
      out += fmt::format("winding {:6.1f} +- {:4.1f} C", a.thermal->winding_temp_C, a.thermal->winding_temp_sigma_C);
      if (a.truth_stale()) {
        out += a.uptime_at_truth_s && a.daemon_uptime_s
                   ? fmt::format(" (the plant's last truth {:.1f}, about {:.0f} s of the daemon's time ago: not compared)",
                                 *a.truth_C, *a.daemon_uptime_s - *a.uptime_at_truth_s)
                   : fmt::format(" (the plant's last truth {:.1f}, no longer reported: not compared)", *a.truth_C);
      } else if (a.compared) {
        // An estimate newer than the last one compared waits for the truth at its sample: the
        // line then says which estimate its error is of.
        const bool newest = a.compared->estimate_C == a.thermal->winding_temp_C;
        out += fmt::format(" ({}true {:6.1f}, error {:+5.1f})",
                           newest ? "" : fmt::format("last compared {:.1f}: ", a.compared->estimate_C),
                           a.compared->truth_C, a.compared->estimate_C - a.compared->truth_C);
      }
      out += a.thermal->calibrated ? "" : " uncalibrated";
      out += a.thermal->stale ? " STALE" : "";
      out += a.thermal->magnet_valid ? fmt::format("  magnet {:5.1f} +- {:4.1f} C", a.thermal->magnet_temp_C,
                                                   a.thermal->magnet_temp_sigma_C)
                                     : "  magnet -";
    } else {
      out += "winding: no estimate yet";
    }
    if (a.thermal && a.thermal->calibration_result != protocol::CalibrationResult::kNone &&
        a.thermal->calibration_result != protocol::CalibrationResult::kDone) {
      // A calibration that did not complete keeps the one in use: say so where it is seen.
      out += fmt::format("  calibration {}", label(protocol::kCalibrationResultLabels,
                                                   static_cast<std::int64_t>(a.thermal->calibration_result)));
    }
    out += a.rs && a.rs->valid ? fmt::format("  Rs {:.2f} mOhm", 1e3 * a.rs->rs_ohm) : "  Rs -";
    if (a.status) {
      out += fmt::format("  {}  limit {:.0f} A", label(protocol::kDriveStateLabels, static_cast<std::int64_t>(a.status->state)),
                         a.status->current_limit_A);
      // MotionValid clear: the drive tracks no shaft (no usable sample), not a shaft at rest.
      out += a.status->motion_valid ? fmt::format("  {:.1f} rad/s {:.1f} Nm", a.status->speed_rad_s, a.status->torque_Nm)
                                    : "  speed -";
      if (a.ambient_source && *a.ambient_source != protocol::AmbientSource::kSensor) {
        out += *a.ambient_source == protocol::AmbientSource::kHeld ? "  ambient HELD" : "  ambient configured";
      }
      // TimeToLimit: until the drive starts to derate (0: it derates now, which the limit shows).
      out += a.status->time_to_limit_valid && a.status->time_to_limit_s > 0.0
                 ? fmt::format("  derates in {:.0f} s", a.status->time_to_limit_s)
                 : "";
    }
    if (a.receive && rejections(*a.receive) != 0U) {
      out += fmt::format("  daemon rejected {} (crc {}, counter {}, range {}, format {}, other {})", rejections(*a.receive),
                         a.receive->rejected_crc, a.receive->rejected_counter, a.receive->rejected_range,
                         a.receive->rejected_format, a.receive->rejected_other);
    }
    if (a.active_faults != 0U) {
      out += "  FAULTS:";
      for (std::size_t k = 1; k < protocol::kFaultCodeCount; ++k) {
        if ((a.active_faults & (1U << k)) != 0U) {
          out += std::string(" ") + label(protocol::kFaultCodeLabels, static_cast<std::int64_t>(k));
        }
      }
    }
    return out;
  }

  // The exit status after the summary: 0, 1 when a --check bound is broken, else 3 when the
  // --csv file did not get every row (a full disk), as for simulate's outputs.
  int finish(const MonitorOptions& o) {
    const int code = summary() ? 0 : 1;
    if (csv_.is_open()) {
      errno = 0;
      csv_.close();
      if (csv_.fail()) {
        const int error = errno;
        std::fprintf(stderr, "monitor: cannot write --csv '%s' (%s): its rows are incomplete\n", o.csv.c_str(),
                     std::strerror(error != 0 ? error : EIO));
        return code == 0 ? 3 : code;
      }
    }
    return code;
  }

  // The summary; false when a --check bound is broken.
  bool summary() {
    erase_block();
    bool ok = true;
    std::printf("\n%llu frame(s)", static_cast<unsigned long long>(frames_));
    std::uint64_t rejected = 0;
    for (std::size_t k = 1; k < rejected_.size(); ++k) {
      rejected += rejected_[k];
    }
    std::printf(", %llu not decodable (", static_cast<unsigned long long>(rejected));
    bool first = true;
    for (std::size_t k = 1; k < rejected_.size(); ++k) {
      if (rejected_[k] != 0U) {
        std::printf("%s%s %llu", first ? "" : ", ", protocol::to_string(static_cast<protocol::DecodeStatus>(k)).data(),
                    static_cast<unsigned long long>(rejected_[k]));
        first = false;
      }
    }
    std::printf("%s)\n", first ? "none" : "");
    if (interface_losses_ != 0U) {
      std::printf("the interface went down %llu time(s) while watching%s\n", static_cast<unsigned long long>(interface_losses_),
                  interface_down_ ? " (and was still down at the end)" : "");
    }
    for (auto& [node, a] : axes_) {
      a.not_compared += a.pending.size();  // after the last truth frame: no truth to interpolate
      a.pending.clear();
      std::printf("%s\n", line(node, a).c_str());
      std::printf("node %2d  injections %llu (%llu accepted), fault reports %llu\n", node,
                  static_cast<unsigned long long>(a.injections), static_cast<unsigned long long>(a.injections_accepted),
                  static_cast<unsigned long long>(a.fault_reports));
      if (a.receive) {
        std::printf("node %2d  daemon: %llu command(s) accepted, %llu frame(s) rejected (RECEIVE_STATUS, unwrapped past 256)\n", node,
                    static_cast<unsigned long long>(a.accepted_seen), static_cast<unsigned long long>(a.rejected_seen));
      }
      if (a.timing) {
        // A window's LatencyMax and DeadlineMisses saturate (6553.5 us, 255): then the worst and
        // the sum are at least what they say (the daemon's log has the exact figures). The
        // HEARTBEAT's count since start (up to 65535) is taken where it says more.
        const Axis::Misses run = a.run_misses();
        const std::uint64_t misses = a.earlier_misses + run.count;
        const bool misses_saturated = a.earlier_misses_saturated || run.saturated;
        const bool since_start = a.earlier_since_start || run.since_start;
        std::printf("node %2d  control loop (last window with steps): sample->command median < %.0f us, p99 < %.0f us; worst %s%.1f us "
                    "over %llu window(s), %s%llu deadline miss(es)%s%s\n",
                    node, a.timing->latency_p50_us, a.timing->latency_p99_us, a.latency_saturated ? "at least " : "",
                    a.worst_latency_us, static_cast<unsigned long long>(a.timing_windows),
                    misses_saturated ? "at least " : "", static_cast<unsigned long long>(misses),
                    since_start ? " since the daemon started (HEARTBEAT)" : "",
                    a.latency_saturated || misses_saturated ? " (saturated on the bus; the daemon's log has the exact figures)"
                                                            : "");
      }
      if (a.n > 0U) {
        const double rms = std::sqrt(a.sq / static_cast<double>(a.n));
        std::printf("node %2d  estimate vs truth above %.0f C: %zu calibrated estimates, error RMS %.2f C, max %.2f C, mean %+.2f C\n",
                    node, o_.threshold_C, a.n, rms, a.max, a.sum / static_cast<double>(a.n));
        if (a.not_compared > 0U) {
          std::printf("node %2d  %llu estimate(s) after the last truth frame not compared\n", node,
                      static_cast<unsigned long long>(a.not_compared));
        }
        if (o_.check_rms_C && rms > *o_.check_rms_C) {
          std::printf("CHECK FAILED: node %d RMS %.2f C > %.2f C\n", node, rms, *o_.check_rms_C);
          ok = false;
        }
        if (o_.check_max_C && a.max > *o_.check_max_C) {
          std::printf("CHECK FAILED: node %d max %.2f C > %.2f C\n", node, a.max, *o_.check_max_C);
          ok = false;
        }
      } else {
        if (a.truth_C) {
          std::printf("node %2d  no calibrated estimate with the truth above %.0f C to compare\n", node, o_.threshold_C);
        }
        // A check with nothing to check is no pass: a CI gate on a capture without a compared
        // estimate (a silent bus, a log without truth frames) passed.
        if (o_.check_rms_C || o_.check_max_C) {
          std::printf("CHECK FAILED: node %d has no compared estimate for --check-rms / --check-max\n", node);
          ok = false;
        }
      }
      if (a.n < o_.min_estimates) {
        std::printf("CHECK FAILED: node %d has %zu compared estimates, fewer than %zu\n", node, a.n, o_.min_estimates);
        ok = false;
      }
    }
    if (axes_.empty() && o_.node) {
      // A node the bus never spoke for: a wrong --node is told, not a silent empty summary.
      std::printf("no frame of node %d (--node) was seen\n", *o_.node);
    }
    if (axes_.empty() && (o_.min_estimates > 0U || o_.check_rms_C || o_.check_max_C)) {
      std::printf("CHECK FAILED: no axis seen\n");
      ok = false;
    }
    return ok;
  }

 private:
  const MonitorOptions& o_;
  std::map<int, Axis> axes_;
  std::uint64_t frames_ = 0;
  std::uint64_t own_drops_ = 0;             // frames the kernel dropped for the live socket
  bool own_drops_unexplained_ = false;      // since then, no command stream in step yet
  std::uint64_t interface_losses_ = 0;      // on_interface: the live socket found it down
  bool interface_down_ = false;
  std::optional<double> last_time_s_;
  bool times_usable_ = true;
  std::array<std::uint64_t, protocol::kDecodeStatusCount> rejected_{};
  std::ofstream csv_;
  std::size_t block_lines_ = 0;  // axis lines on the terminal below the cursor's line
};

int run_monitor(MonitorOptions o) {
  o.in_place = o.log.empty() && isatty(STDOUT_FILENO) == 1 && o.csv.empty() && !o.plain;
  std::optional<Monitor> monitor;
  try {
    monitor.emplace(o);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "monitor: %s\n", e.what());
    return 2;
  }
  Monitor& m = *monitor;
  if (!o.log.empty()) {
    TextInput input;
    if (const std::string problem = input.open(o.log); !problem.empty()) {
      std::fprintf(stderr, "monitor: %s\n", problem.c_str());
      return 2;
    }
    std::uint64_t malformed = 0;
    std::uint64_t frames = 0;
    std::uint64_t line_number = 0;
    std::string line;
    for (bool too_long = false; input.next_line(line, too_long);) {
      ++line_number;
      const candump::ParseResult parsed = TextInput::parse_candump(line, too_long);
      if (parsed.ok()) {
        ++frames;
        const auto& stamp = parsed.record->timestamp;
        m.on_frame(parsed.record->frame,
                   stamp ? std::optional<double>(std::chrono::duration<double>(*stamp).count()) : std::nullopt);
      } else if (!line.empty()) {
        // Which lines and why, as decode says it (the count alone named neither), the first ten.
        ++malformed;
        if (malformed <= kMaxListedBadLines) {
          std::fprintf(stderr, "monitor: line %llu is not a candump frame: %s\n", static_cast<unsigned long long>(line_number),
                       parsed.error.c_str());
        } else if (malformed == kMaxListedBadLines + 1U) {
          std::fprintf(stderr, "monitor: more lines are not candump frames; the first %llu are listed, the count has them all\n",
                       static_cast<unsigned long long>(kMaxListedBadLines));
        }
      }
    }
    if (input.failed()) {
      std::fprintf(stderr, "monitor: error reading '%s'\n", input.name().c_str());
      return 2;
    }
    if (malformed != 0U) {
      std::printf("%llu line(s) were not candump frames\n", static_cast<unsigned long long>(malformed));
      if (frames == 0U) {
        std::fprintf(stderr, "monitor: %s\n", input.no_frame_error().c_str());
        return 2;
      }
    }
    return m.finish(o);
  }
  hal::SocketCanConfig config;
  config.interface = o.iface;
  config.fd = true;
  // A large receive queue: a monitor that falls behind a fast loop for a moment (a loaded
  // host, User-Mode Linux) should not lose the frames it counts. SO_RCVBUF asks for it; the
  // kernel grants at most net.core.rmem_max (drops beyond are reported, on_own_drops).
  config.receive_buffer_bytes = 16 * 1024 * 1024;
  hal::Status error;
  std::unique_ptr<hal::SocketCanBus> bus = hal::SocketCanBus::open(config, error);
  if (!bus) {
    config.fd = false;  // a classic-only interface still carries every user-facing frame
    bus = hal::SocketCanBus::open(config, error);
  }
  if (!bus) {
    std::fprintf(stderr, "monitor: cannot open the CAN bus: %s\n", error.message().c_str());
    return 2;
  }
  if (const int granted = bus->receive_buffer_granted_bytes(); granted > 0 && granted < config.receive_buffer_bytes) {
    std::fprintf(stderr,
                 "monitor: the socket's receive queue is %d KiB, not the %d KiB asked (net.core.rmem_max caps it "
                 "without CAP_NET_ADMIN): a monitor that falls behind a fast loop drops frames sooner, and says so\n",
                 granted / 1024, config.receive_buffer_bytes / 1024);
  }
  (void)hal::install_stop_signals();
  const std::int64_t start = hal::monotonic_ns();
  hal::ReceivedFrame r;
  auto over = [&] {
    return o.duration_s && static_cast<double>(hal::monotonic_ns() - start) * 1e-9 > *o.duration_s;
  };
  while (!hal::stop_requested().load() && !over()) {
    const hal::ReceiveStatus got = bus->receive(r, std::chrono::milliseconds{100});
    m.on_own_drops(bus->counters().rx_overflow);
    if (got == hal::ReceiveStatus::kFrame && !r.frame.error) {
      m.on_frame(r.frame, r.timestamp_ns != 0 ? std::optional<double>(static_cast<double>(r.timestamp_ns) * 1e-9) : std::nullopt);
    } else if (got == hal::ReceiveStatus::kInterfaceDown) {
      // Wait for the interface and reopen the socket (as the daemon does); stop waiting on a
      // signal or at the end of --duration.
      m.on_interface(o.iface, false);
      std::atomic<bool> give_up{false};
      const bool back = hal::wait_and_reopen(*bus, std::chrono::milliseconds{200}, std::chrono::milliseconds{100}, give_up, [&] {
        if (hal::stop_requested().load() || over()) {
          give_up.store(true);
        }
      });
      if (back) {
        m.on_interface(o.iface, true);
      }
    }
  }
  return m.finish(o);
}

}  // namespace

void register_monitor_command(CLI::App& app, int& exit_code) {
  auto o = std::make_shared<MonitorOptions>();
  CLI::App* cmd = app.add_subcommand("monitor", "Watch the axes on a bus (or in a candump log): temperatures, state, faults");
  cmd->add_option("iface", o->iface, "CAN interface to open (e.g. vcan0)")
      ->check(pmsm::cli::text_rule(pmsm::hal::can_interface_name_problem, "NAME"));
  CLI::Option* log = cmd->add_option("--log", o->log, "read a candump log instead ('-': stdin)")->check(pmsm::cli::file_name());
  cmd->add_option("--node", o->node, "only this node")->check(pmsm::cli::integer_in_range(0, 15));
  cmd->add_option("--every", o->every_s, "seconds of drive time between lines per axis")->check(pmsm::cli::number_in_range(0.0, 1e6))->capture_default_str();
  cmd->add_option("--threshold", o->threshold_C, "compare with the truth above this winding temperature, C")
      ->check(pmsm::cli::number_in_range(-273.15, 1000.0))
      ->capture_default_str();
  // The checks gate CI runs: a NaN bound would pass every run (no error is above NaN).
  cmd->add_option("--check-rms", o->check_rms_C, "exit 1 when an axis's error RMS is above this, C")
      ->check(pmsm::cli::non_negative(1000.0));
  cmd->add_option("--check-max", o->check_max_C, "exit 1 when an axis's largest error is above this, C")
      ->check(pmsm::cli::non_negative(1000.0));
  cmd->add_option("--min-estimates", o->min_estimates, "exit 1 when an axis has fewer compared estimates")
      ->check(pmsm::cli::number_in_range(0.0, 1e9));
  cmd->add_option("--csv", o->csv, "write every THERMAL_ESTIMATE with the truth beside it as CSV")
      ->check(pmsm::cli::file_name());
  // (A log is read to its end: a duration given with it would be ignored without a word.)
  cmd->add_option("--duration", o->duration_s, "stop watching a live bus after this many seconds")
      ->check(pmsm::cli::positive(1e7))
      ->excludes(log);
  cmd->add_flag("--plain", o->plain, "one line per update even on a terminal (no redraw in place)");
  cmd->callback([o, &exit_code, cmd] {
    if (o->iface.empty() == o->log.empty()) {
      std::fprintf(stderr, "monitor: give either an interface or --log FILE\n%s", cmd->help().c_str());
      exit_code = 2;
      return;
    }
    // The CSV is opened (emptied) before the log is read: over the log, it would erase it.
    if (!o->csv.empty() && !o->log.empty() && o->log != "-" && common::same_file(o->csv, o->log)) {
      std::fprintf(stderr, "monitor: --csv '%s' would write over the log it reads (--log '%s'): refusing\n",
                   o->csv.c_str(), o->log.c_str());
      exit_code = 2;
      return;
    }
    exit_code = run_monitor(*o);
  });
}

}  // namespace pmsm::app
