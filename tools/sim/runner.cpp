#include "runner.hpp"

#include "calibration_file.hpp"

#include <cerrno>
#include <cstring>
#include <unistd.h>

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <condition_variable>
#include <deque>
#include <exception>
#include <fstream>
#include <limits>
#include <memory>
#include <mutex>
#include <numbers>
#include <optional>
#include <stdexcept>
#include <string_view>
#include <thread>

#include <fmt/format.h>

#include "json_writer.hpp"
#include "drive_node.hpp"
#include "truth_history.hpp"
#include "pmsm/plant/plant.hpp"

namespace pmsm::app {
namespace {

// JSON writes a non-finite number as null: "no value", never a plausible-looking number.
constexpr double kNan = std::numeric_limits<double>::quiet_NaN();

std::string method_name(const ControllerConfig& c) {
  const core::DriveConfig& d = c.drive;
  if (d.estimator == core::EstimatorKind::kNoInjection) {
    return "no-injection";
  }
  if (d.estimator == core::EstimatorKind::kNone || d.injection.method == core::InjectionMethod::kNone) {
    return "thermal-model-only";
  }
  return fmt::format("{} {}", core::to_string(d.injection.method), core::to_string(d.injection.separation));
}

constexpr std::uint64_t kFastEvery = 10;  // 1 kHz at 10 kHz PWM

// A fast-rate record for the disturbance figures: means over 1 ms, so that the torque
// ripple of the EMF harmonics (hundreds of hertz) does not pose as a disturbance.
struct FastRow {
  double speed_rad_s;
  double torque_Nm;
  bool injection;
  bool counted;   // inside the metric window (after start-up and calibration)
};

struct Disturbance {
  double during = 0.0;
  double during_sum = 0.0;      // of the rows judged during injection (their mean)
  double outside = 0.0;
  std::size_t during_row = 0;   // where the largest difference during injection occurred
  std::size_t during_rows = 0;  // rows judged during injection and away from it: a figure of
  std::size_t outside_rows = 0; // no row is no figure (null), not a difference of zero
};

// Replaces each row's torque with its trailing moving average over the last `kWindow` rows.
class TorqueSmoother {
 public:
  double next(double torque_Nm) noexcept {
    const std::size_t slot = count_ % kWindow;
    const double oldest = ring_[slot];
    sum_ += torque_Nm;
    if (count_ >= kWindow) {
      sum_ -= oldest;
    }
    ring_[slot] = torque_Nm;
    ++count_;
    return sum_ / static_cast<double>(std::min(count_, kWindow));
  }

 private:
  static constexpr std::size_t kWindow = 10;  // 10 ms of 1 ms rows
  std::array<double, kWindow> ring_{};
  double sum_ = 0.0;
  std::size_t count_ = 0;
};

// The disturbance figures, computed as the rows of the run and of its twin arrive, with
// memory bounded by the windows (a few hundred rows), not by the run's length:
// - torque is compared as a 10 ms trailing moving average: the EMF harmonics' torque ripple
//   (hundreds of hertz) is in both runs, but at rotor angles that drift apart over a long run;
// - a row counts only where the twin (no injection) runs steadily: every row within
//   `half` rows of it has a speed within `tolerance` of its own centred moving average over
//   2 half + 1 rows (the scenario's load and speed steps are transients in both runs, and a
//   millisecond's shift of such a transient would pose as a disturbance); the first and the
//   last rows, whose windows leave the run, are not steady;
// - the largest difference during injection (and `after` rows past it) and outside.
// Row k is judged once row k + 2 half + 1 has arrived.
class DisturbanceMeter {
 public:
  DisturbanceMeter(std::size_t after, double rated_speed_rad_s, double rated_torque_Nm) noexcept
      : half_(after / 2),
        after_(after),
        speed_floor_(0.1 * rated_speed_rad_s),
        rated_torque_Nm_(rated_torque_Nm),
        since_injection_(after + 1) {}

  void add(FastRow run, FastRow twin) {
    run.torque_Nm = run_torque_.next(run.torque_Nm);
    twin.torque_Nm = twin_torque_.next(twin.torque_Nm);
    const std::size_t n = rows_seen_++;
    rows_.push_back({run, twin});
    const std::size_t width = 2 * half_ + 1;
    if (n < width) {
      speed_sum_ += twin.speed_rad_s;  // the first window: rows 0 .. 2 half
      return;
    }
    // Row j = n - half - 1 has its whole centred window (rows j - half .. j + half) summed.
    const std::size_t j = n - half_ - 1;
    const double mean = speed_sum_ / static_cast<double>(width);
    const double speed_j = row(j).twin.speed_rad_s;
    const bool steady_j = std::abs(speed_j - mean) <= kTolerance * std::max(std::abs(mean), speed_floor_);
    speed_sum_ += twin.speed_rad_s - row(j - half_).twin.speed_rad_s;
    steady_run_ = steady_j ? steady_run_ + 1 : 0;  // consecutive steady rows ending at j
    // Row k = j - half: steady if rows max(0, k - half) .. k + half all are; rows before `half`
    // never are (their window leaves the run).
    const std::size_t k = j - half_;
    const std::size_t first = k >= half_ ? k - half_ : 0;
    judge(k, first >= half_ && steady_run_ >= j - first + 1);
    while (rows_seen_ - rows_.size() < n - 2 * half_) {
      rows_.pop_front();  // row n - 2 half is the oldest the next row needs
    }
  }

  // A twin forked before the next row: until the fork it is the run, so the torque rows its
  // moving average trails are the run's (not those of a twin that ended just before).
  void fork() noexcept { twin_torque_ = run_torque_; }

  [[nodiscard]] std::size_t after() const noexcept { return after_; }
  [[nodiscard]] const Disturbance& speed() const noexcept { return speed_; }
  [[nodiscard]] const Disturbance& torque() const noexcept { return torque_; }

 private:
  static constexpr double kTolerance = 0.005;
  struct Pair {
    FastRow run;
    FastRow twin;
  };

  [[nodiscard]] const Pair& row(std::size_t index) const { return rows_[index - (rows_seen_ - rows_.size())]; }

  void judge(std::size_t k, bool steady) {
    const Pair& p = row(k);
    since_injection_ = p.run.injection ? 0 : since_injection_ + 1;
    if (!p.run.counted || !steady) {
      return;
    }
    const bool during = since_injection_ <= after_;
    const double speed_scale = std::max(std::abs(p.twin.speed_rad_s), speed_floor_);
    record(speed_, during, k, std::abs(p.run.speed_rad_s - p.twin.speed_rad_s) / speed_scale);
    record(torque_, during, k, std::abs(p.run.torque_Nm - p.twin.torque_Nm) / rated_torque_Nm_);
  }

  static void record(Disturbance& d, bool during, std::size_t k, double deviation) noexcept {
    if (!during) {
      ++d.outside_rows;
      d.outside = std::max(d.outside, deviation);
      return;
    }
    ++d.during_rows;
    d.during_sum += deviation;
    if (deviation > d.during) {
      d.during = deviation;
      d.during_row = k;
    }
  }

  std::size_t half_;
  std::size_t after_;
  double speed_floor_;
  double rated_torque_Nm_;
  TorqueSmoother run_torque_;
  TorqueSmoother twin_torque_;
  std::deque<Pair> rows_;
  std::size_t rows_seen_ = 0;
  double speed_sum_ = 0.0;
  std::size_t steady_run_ = 0;
  std::size_t since_injection_;  // rows since the last injection row (none before the run)
  Disturbance speed_;
  Disturbance torque_;
};

// One simulated drive on its plant, and what the runner keeps between its periods. The run is
// one; its twin without injection is a copy of it (the copy carries on bit for bit: the plant's
// noise generator and the drive's whole state are values).
struct Rig {
  Rig(const Scenario& scenario, const ControllerConfig& controller)
      : plant(scenario.plant),
        node(controller, scenario.supervisor, PublishRates{}) {}

  // The period's set-points as the scenario gives them at the plant's time, with the plant's
  // ambient and the start of the calibration (in real time, for the drive and the plant alike).
  NodeInputs inputs(const ScenarioConfig& sc) {
    const double t = plant.time_s();
    NodeInputs cmd;
    cmd.mode = sc.mode;
    cmd.speed_ref_rad_s = sc.speed_rad_s.at(t);
    cmd.torque_ref_Nm = sc.torque_Nm.at(t);
    // The drive's ambient / coolant sensor reads the scenario's ambient.
    cmd.ambient_C = sc.ambient_profile.empty() ? sc.ambient_C : sc.ambient_profile.at(t);
    if (!sc.ambient_profile.empty()) {
      plant.set_ambient_C(cmd.ambient_C);
    }
    if (sc.calibrate && !calibration_started && t >= sc.calibrate_at_s) {
      // The drive calibrates at what it knows: its ambient sensor (the motor is soaked at
      // rest), never the plant's state.
      cmd.start_calibration = true;
      calibration_started = true;
      if (sc.calibration_real_time) {
        plant.set_thermal_acceleration(1.0);  // the drive's model: DriveNode, at the same step
        real_time_calibration = true;
      }
    }
    return cmd;
  }

  // After the drive's step: a calibration in real time that ended gives the plant back its
  // thermal acceleration. Returns whether it did.
  bool end_real_time_calibration(double acceleration) {
    if (!real_time_calibration || node.controller().telemetry().calibrating) {
      return false;
    }
    plant.set_thermal_acceleration(acceleration);
    real_time_calibration = false;
    return true;
  }

  // The period's share of the 1 ms row (speed and torque at the sample the step consumed); the
  // row when period k completes one.
  std::optional<FastRow> accumulate(std::uint64_t k, const plant::PlantState& truth, bool injection, bool counted) {
    fast_injection = fast_injection || injection;
    fast_speed_sum += truth.omega_m_rad_s;
    fast_torque_sum += truth.torque_em_Nm;
    if (k % kFastEvery != kFastEvery - 1) {
      return std::nullopt;
    }
    const FastRow row{fast_speed_sum / kFastEvery, fast_torque_sum / kFastEvery, fast_injection, counted};
    fast_injection = false;
    fast_speed_sum = 0.0;
    fast_torque_sum = 0.0;
    return row;
  }

  // The plant's period under the drive's command.
  void finish(const NodeStep& step) {
    plant.step(*step.command);
    if (plant.diverged()) {
      throw PlantDivergedError(fmt::format(
          "{}the plant's model diverged at {:.6g} s (its currents or speed are no longer numbers): a machine its "
          "integration cannot follow; check [plant.motor] and plant.simulation.substeps",
          twin ? "the disturbance metric's twin (the run without injection): " : "", plant.diverged_at_s()));
    }
  }

  plant::Plant plant;
  DriveNode node;
  bool twin = false;  // the disturbance metric's twin (its errors say so)
  bool calibration_started = false;
  bool real_time_calibration = false;
  bool fast_injection = false;
  double fast_speed_sum = 0.0;
  double fast_torque_sum = 0.0;
};

// The disturbance metric's twin: the same drive without injection. Running a second drive
// beside the whole run would double the simulation's cost for the few hundred milliseconds
// around each event that the metric compares; the twin instead forks from the run where an
// event begins and lives until the metric has judged the event's last row.
// - A snapshot of the run is taken between events: a few periods before the next scheduled
//   event is due, and every RunOptions::twin_snapshot_periods for the events a request starts
//   (a copy of the plant and the drive: about 40,000 instructions, the pair recorder's
//   samples copied only as far as it recorded).
// - When the run's drive starts an event in period k, the twin is the snapshot stepped to
//   period k - 1 exactly as the run was (the same state, set-points and noise), then told to
//   start no event (DriveController::hold_injection_events) before its period k. Until the
//   event the two are the same bit for bit; from it on they differ by the injection alone,
//   noise included.
// - It lives until the run is between events again and the rows the metric judges as during
//   the event (`after` rows past its last injection row) have their steadiness windows
//   (2 half + 1 rows more); away from it the twin's rows are the run's own.
// The run's side (TwinSchedule) decides all of that from the run alone; the twin's side
// (TwinStepper) steps the twin as far as the rows asked of it, on the run's thread or on one of
// its own (TwinLink): the figures are the same either way.

// The run's side: the snapshots, and when the twin runs.
class TwinSchedule {
 public:
  // The twin's rows for an event: `after` rows past its last injection row are judged as
  // during it, each once 2 half + 1 rows more have come (DisturbanceMeter::add), with two to
  // spare; `extra_rows` more (RunOptions::twin_extra_rows).
  TwinSchedule(const Rig& run, std::size_t after, std::uint64_t snapshot_every, std::size_t extra_rows)
      : snapshot_every_(std::max<std::uint64_t>(1, snapshot_every)),
        snapshot_(run),
        tail_rows_(after + 2 * (after / 2) + 2 + extra_rows) {}

  // At the start of period k of the run, before its step.
  void before(const Rig& run, std::uint64_t k) {
    const core::DriveController& drive = run.node.controller();
    if (alive_ || !drive.between_injection_events()) {
      return;
    }
    const double next_event_s = drive.next_injection_event_s();
    const bool event_due = next_event_s != snapshot_event_s_ &&
                           next_event_s - drive.telemetry().time_s <= kLeadPeriods * run.plant.period_s();
    if (event_due || snapshot_stale_ || k >= snapshot_k_ + snapshot_every_) {
      snapshot_ = run;
      snapshot_k_ = k;
      snapshot_stale_ = false;
      snapshot_event_s_ = event_due ? next_event_s : snapshot_event_s_;
    }
  }

  // After the run's drive stepped: whether the twin forks here (the drive has just begun an
  // event), from snapshot() taken at the start of period snapshot_k(). Not in a calibration:
  // its rows are never counted (the figures start when it ends), and a twin held in it would
  // stay calibrating, and time out, beside a run that has stored its calibration.
  bool fork(const Rig& run) {
    const core::DriveController& drive = run.node.controller();
    if (alive_ || drive.between_injection_events() || drive.telemetry().calibrating) {
      return false;
    }
    alive_ = true;
    rows_since_injection_ = 0;
    return true;
  }
  [[nodiscard]] const Rig& snapshot() const noexcept { return snapshot_; }
  [[nodiscard]] std::uint64_t snapshot_k() const noexcept { return snapshot_k_; }

  // A row of the run: whether the twin gives this row; ends the twin once the metric needs it
  // no more (or the run has begun a calibration, fork()).
  bool twin_row(const Rig& run, const FastRow& run_row) {
    if (!alive_) {
      return false;
    }
    const core::DriveController& drive = run.node.controller();
    if (drive.telemetry().calibrating) {
      alive_ = false;
      snapshot_stale_ = true;
      return false;
    }
    rows_since_injection_ = run_row.injection ? 0 : rows_since_injection_ + 1;
    if (rows_since_injection_ >= tail_rows_ && drive.between_injection_events()) {
      alive_ = false;
      snapshot_stale_ = true;  // the next snapshot as soon as the run allows one
    }
    return true;
  }

  // The run's plant got its thermal acceleration back (the end of a real-time calibration): no
  // snapshot from before; whether the running twin must follow.
  bool acceleration_changed() {
    snapshot_stale_ = true;
    return alive_;
  }

 private:
  static constexpr double kLeadPeriods = 3.0;  // the scheduled event's snapshot: at most this early

  std::uint64_t snapshot_every_;  // RunOptions::twin_snapshot_periods
  Rig snapshot_;
  std::uint64_t snapshot_k_ = 0;
  double snapshot_event_s_ = -1.0;  // the scheduled event the last snapshot was taken for
  bool snapshot_stale_ = false;
  bool alive_ = false;
  std::size_t tail_rows_;
  std::size_t rows_since_injection_ = 0;
};

// The twin's side: steps the twin as far as it is asked.
class TwinStepper {
 public:
  // `acceleration`: the scenario's thermal acceleration, which a real-time calibration's end
  // gives the plant back.
  TwinStepper(const Rig& run, const ScenarioConfig& sc, double acceleration)
      : twin_(run), sc_(sc), acceleration_(acceleration) {}

  // The twin from a snapshot of the run taken at the start of period snapshot_k, stepped as
  // the run was to period k - 1 (its rows are the run's), then without events from period k.
  void fork(const Rig& snapshot, std::uint64_t snapshot_k, std::uint64_t k) {
    const auto start = std::chrono::steady_clock::now();
    twin_ = snapshot;
    twin_.twin = true;
    for (std::uint64_t j = snapshot_k; j < k; ++j) {
      period(j, true);
    }
    twin_.node.controller().hold_injection_events();
    // Nor does it ask for the scenario's calibration: the run asks, and if its drive accepts,
    // the twin ends (TwinSchedule::twin_row); if it refuses, the twin carries on without one
    // as the run does, its plant at the run's thermal acceleration.
    twin_.calibration_started = true;
    next_k_ = k;
    wall_s_ += std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  }

  // The run's plant got back its thermal acceleration in its period k (between its drive's step
  // and its plant's): the twin's too, from its period k.
  void acceleration_changed(std::uint64_t k) {
    if (k > 0) {
      advance(k - 1);
    }
    twin_.plant.set_thermal_acceleration(acceleration_);
    twin_.real_time_calibration = false;
  }

  // The twin's row that ends with period k (rows are asked for in order, each once).
  FastRow row(std::uint64_t k) {
    const std::optional<FastRow> r = advance(k);
    if (!r) {
      throw std::logic_error(fmt::format("the disturbance metric's twin was asked for its row of period {} past it", k));
    }
    return *r;
  }

  [[nodiscard]] double wall_s() const noexcept { return wall_s_; }
  [[nodiscard]] std::uint64_t periods() const noexcept { return periods_; }

 private:
  // Steps the twin through period k; the row its period k completed, if any.
  std::optional<FastRow> advance(std::uint64_t k) {
    const auto start = std::chrono::steady_clock::now();
    std::optional<FastRow> row;
    for (; next_k_ <= k; ++next_k_) {
      row = period(next_k_, false);
      ++periods_;
    }
    wall_s_ += std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
    return row;
  }

  // One period of the twin: in a catch-up (`replay`) the run's own, afterwards without events
  // and with the run's thermal acceleration (acceleration_changed).
  std::optional<FastRow> period(std::uint64_t k, bool replay) {
    Rig& t = twin_;
    const NodeInputs cmd = t.inputs(sc_);
    const NodeStep& step = t.node.step(&t.plant.sample(), cmd);
    if (replay) {
      t.end_real_time_calibration(acceleration_);  // the run's rule: the twin is the run until the fork
    }
    const std::optional<FastRow> row = t.accumulate(k, t.plant.state(), false, false);
    t.finish(step);
    return row;
  }

  Rig twin_;  // a copy of the snapshot once forked (assigned: no allocation after the first)
  const ScenarioConfig& sc_;
  double acceleration_;
  std::uint64_t next_k_ = 0;  // the twin's next period
  double wall_s_ = 0.0;
  std::uint64_t periods_ = 0;
};

// A bounded channel of chunks from one producer thread to one consumer: the producer waits
// while it is full, the consumer while it is empty; abandon() lets a producer finish without a
// consumer.
template <typename T>
class Channel {
 public:
  static constexpr std::size_t kChunk = 256;
  static constexpr std::size_t kMaxChunks = 4;

  void push(T item) {
    chunk_.push_back(std::move(item));
    if (chunk_.size() == kChunk) {
      flush();
    }
  }
  // The producer is done (also after an exception): flushes and wakes the consumer.
  void close() {
    flush();
    const std::lock_guard lock(mutex_);
    closed_ = true;
    changed_.notify_all();
  }
  void abandon() {
    const std::lock_guard lock(mutex_);
    abandoned_ = true;
    chunks_.clear();
    changed_.notify_all();
  }
  // Hands over what was pushed so far, before its chunk is full.
  void flush() {
    if (chunk_.empty()) {
      return;
    }
    std::unique_lock lock(mutex_);
    changed_.wait(lock, [&] { return chunks_.size() < kMaxChunks || abandoned_; });
    if (!abandoned_) {
      chunks_.push_back(std::move(chunk_));
      changed_.notify_all();
    }
    chunk_ = std::vector<T>();
    chunk_.reserve(kChunk);
  }
  // The next chunk, waiting for it; empty once the producer closed and everything was taken.
  std::vector<T> pop() {
    std::unique_lock lock(mutex_);
    changed_.wait(lock, [&] { return !chunks_.empty() || closed_ || abandoned_; });
    if (chunks_.empty()) {
      return {};
    }
    std::vector<T> chunk = std::move(chunks_.front());
    chunks_.pop_front();
    changed_.notify_all();
    return chunk;
  }

 private:
  std::vector<T> chunk_;  // the producer's own
  std::mutex mutex_;
  std::condition_variable changed_;
  std::deque<std::vector<T>> chunks_;
  bool closed_ = false;
  bool abandoned_ = false;
};

// Connects the run's side to the twin's and the meter: directly, or through a channel to a
// thread of the twin's own (RunOptions::twin_thread). Either way the twin's side sees the same
// calls in the same order.
class TwinLink {
 public:
  TwinLink(const Rig& run, const ScenarioConfig& sc, double acceleration, DisturbanceMeter& meter, bool thread)
      : stepper_(run, sc, acceleration), meter_(meter) {
    if (thread) {
      for (std::unique_ptr<Rig>& buffer : buffers_) {
        buffer = std::make_unique<Rig>(run);
        free_.push_back(buffer.get());
      }
      thread_ = std::thread([this] { consume(); });
    }
  }
  TwinLink(const TwinLink&) = delete;
  TwinLink& operator=(const TwinLink&) = delete;
  ~TwinLink() {
    if (thread_.joinable()) {
      stop();
      thread_.join();
    }
  }

  void fork(const Rig& snapshot, std::uint64_t snapshot_k, std::uint64_t k) {
    if (!thread_.joinable()) {
      stepper_.fork(snapshot, snapshot_k, k);
      meter_.fork();
      return;
    }
    // A snapshot buffer the twin's thread has done with (it holds at most two): the memory
    // stays what it was at the start, however far behind the twin's thread falls.
    Rig* buffer = nullptr;
    {
      std::unique_lock lock(buffers_mutex_);
      buffers_free_.wait(lock, [&] { return !free_.empty() || stopped_; });
      if (stopped_) {
        return;  // the twin's side failed: finish() reports why
      }
      buffer = free_.back();
      free_.pop_back();
    }
    *buffer = snapshot;
    channel_.push(Message{Message::Kind::kFork, k, snapshot_k, buffer, {}, false});
    channel_.flush();  // in the twin's hands before the next fork may wait for its buffer
  }
  void acceleration_changed(std::uint64_t k) {
    if (!thread_.joinable()) {
      stepper_.acceleration_changed(k);
      return;
    }
    channel_.push(Message{Message::Kind::kAcceleration, k, 0, nullptr, {}, false});
  }
  // The run's row that ends with period k, and whether the twin gives its own.
  void row(std::uint64_t k, const FastRow& run_row, bool twin) {
    if (!thread_.joinable()) {
      meter_.add(run_row, twin ? stepper_.row(k) : run_row);
      return;
    }
    channel_.push(Message{Message::Kind::kRow, k, 0, nullptr, run_row, twin});
  }

  // The run is done: waits for the twin's side; rethrows what stopped it.
  const TwinStepper& finish() {
    if (thread_.joinable()) {
      channel_.close();
      thread_.join();
    }
    if (error_) {
      std::rethrow_exception(error_);
    }
    return stepper_;
  }

 private:
  struct Message {
    enum class Kind : std::uint8_t { kFork, kAcceleration, kRow };
    Kind kind;
    std::uint64_t k;           // the fork's period, the acceleration's, the row's last
    std::uint64_t snapshot_k;  // kFork
    Rig* snapshot;             // kFork: one of buffers_
    FastRow row;
    bool twin;
  };

  void consume() {
    try {
      for (std::vector<Message> chunk = channel_.pop(); !chunk.empty(); chunk = channel_.pop()) {
        for (Message& m : chunk) {
          switch (m.kind) {
            case Message::Kind::kFork:
              stepper_.fork(*m.snapshot, m.snapshot_k, m.k);
              meter_.fork();
              {
                const std::lock_guard lock(buffers_mutex_);
                free_.push_back(m.snapshot);
              }
              buffers_free_.notify_one();
              break;
            case Message::Kind::kAcceleration:
              stepper_.acceleration_changed(m.k);
              break;
            case Message::Kind::kRow:
              meter_.add(m.row, m.twin ? stepper_.row(m.k) : m.row);
              break;
          }
        }
      }
    } catch (...) {
      error_ = std::current_exception();
      stop();  // the run's pushes and forks return at once from here on
    }
  }

  void stop() {
    channel_.abandon();
    {
      const std::lock_guard lock(buffers_mutex_);
      stopped_ = true;
    }
    buffers_free_.notify_all();
  }

  TwinStepper stepper_;
  DisturbanceMeter& meter_;
  Channel<Message> channel_;
  std::array<std::unique_ptr<Rig>, 2> buffers_;  // snapshots on their way to the twin's thread
  std::mutex buffers_mutex_;
  std::condition_variable buffers_free_;
  std::vector<Rig*> free_;  // of buffers_, guarded by buffers_mutex_
  bool stopped_ = false;    // guarded by buffers_mutex_
  std::exception_ptr error_;
  std::thread thread_;  // last: started once the rest is built
};

// One closed-loop run; with `meter`, its twin without injection beside it (ForkedTwin) and
// the disturbance figures.
SimulationResult run_once(const Scenario& scenario, const RunOptions& options, DisturbanceMeter* meter) {
  const ScenarioConfig& sc = scenario.scenario;
  SimulationResult result;
  result.scenario = sc.name;
  result.error_threshold_C = sc.error_threshold_C;
  result.method = method_name(scenario.controller);
  result.estimator = scenario.controller.drive.estimator;
  result.supervisor = scenario.supervisor;

  // The drive's whole per-sample path, as pmsm-thermald runs it; the runner only feeds it
  // the plant's samples and the scenario's set-points, and measures.
  // In a scenario operation.calibration_real_time decides for the drive and the plant alike.
  ControllerConfig controller_config = scenario.controller;
  controller_config.calibration_real_time = sc.calibration_real_time;
  Rig run(scenario, controller_config);
  plant::Plant& plant = run.plant;
  DriveNode& node = run.node;
  core::DriveController& drive = node.controller();
  std::optional<TwinSchedule> twin;
  std::optional<TwinLink> twin_link;
  if (meter != nullptr) {
    twin.emplace(run, meter->after(), options.twin_snapshot_periods, options.twin_extra_rows);
    twin_link.emplace(run, sc, scenario.plant.thermal.acceleration, *meter, options.twin_thread);
  }

  const double ts = plant.period_s();
  const auto periods = static_cast<std::uint64_t>(std::llround(sc.duration_s / ts));
  const auto log_every = std::max<std::uint64_t>(1, static_cast<std::uint64_t>(std::llround(sc.log_period_s / ts)));

  if (options.keep_series) {
    result.series.reserve(periods / log_every + 1);
  }

  std::uint32_t latched_before = 0;  // the supervisor's latched faults after the previous period
  double metrics_from_s = -1.0;  // -1: not yet (calibration, or the first estimate, pending)
  core::OutcomeCounts event_pairs{};  // pairs since the last event or calibration ended: the next one's
  core::AbortCounts event_aborts{};   // the same by abort cause
  std::string calibration_line;       // --events: a calibration's end, after the step's own event
  bool calibration_ended = false;     // in this step (a refusal is not an end)
  bool was_calibrating = false;
  std::size_t covered = 0;        // counted samples with the truth inside +-2 sigma
  double band_sum_C = 0.0;        // their 2 sigma, summed
  double injection_energy_J = 0.0;
  std::uint64_t injection_periods = 0;
  TruthHistory history;
  {
    const plant::PlantState start = plant.state();
    history.record(plant.time_s(), start.rs_ohm, start.winding_temp_C);
  }
  double sq_err = 0.0, sum_err = 0.0, sq_rs = 0.0, sq_magnet = 0.0;
  std::size_t rs_compared = 0;
  double rel_rs_sum = 0.0;  // fused estimates' relative error at their own time
  std::size_t rel_rs_count = 0;
  std::size_t magnet_covered = 0;

  const auto wall_start = std::chrono::steady_clock::now();
  auto last_progress = wall_start;
  const bool tty = options.progress && isatty(STDERR_FILENO) != 0;

  for (std::uint64_t k = 0; k < periods; ++k) {
    const double t = plant.time_s();
    if (twin) {
      twin->before(run, k);
    }
    const NodeInputs cmd = run.inputs(sc);
    const NodeStep& step = node.step(&plant.sample(), cmd);
    if (twin && twin->fork(run)) {
      twin_link->fork(twin->snapshot(), twin->snapshot_k(), k);
    }
    const core::DriveTelemetry& tel = drive.telemetry();
    if (const std::uint32_t latched = node.supervisor().status().latched_mask; latched != latched_before) {
      // A code latched for the first time: when (the supervisor counts the latches).
      for (std::size_t c = 1; c < core::kFaultCodeCount; ++c) {
        const std::uint32_t bit = core::Supervisor::bit(static_cast<core::FaultCode>(c));
        if ((latched & bit) != 0U && (latched_before & bit) == 0U && node.supervisor().counts()[c] == 1U) {
          result.faults[c].first_s = t;
        }
      }
      latched_before = latched;
    }
    const bool log_now = k % log_every == 0;
    const bool fast_now = k % kFastEvery == kFastEvery - 1;
    const plant::PlantState truth = plant.state();  // built in place: no copy of the whole record a period
    // Every 10 periods, and at a publication between them, so that an age under a millisecond
    // finds its truth too (records stay in time order).
    if (fast_now || drive.last_estimate()) {
      history.record(plant.time_s(), truth.rs_ohm, truth.winding_temp_C);
    }

    if (run.end_real_time_calibration(scenario.plant.thermal.acceleration) && twin && twin->acceleration_changed()) {
      twin_link->acceleration_changed(k);
    }
    if (drive.inverter_sweep_completed()) {
      result.inverter_sweep = *drive.inverter_sweep_completed();
      result.inverter_sweep_time_s = t;
    }
    if (drive.angle_check_completed()) {
      result.angle_check = *drive.angle_check_completed();
      result.angle_check_time_s = t;
    }
    if (drive.calibration_just_failed()) {
      result.calibration_failure = tel.calibration_failure;
      result.calibration_failure_time_s = t;
      const bool measured = core::refused_measured_rs0(tel.calibration_failure);
      result.calibration_failure_rs0_ohm = measured ? tel.calibration_rs0_ohm : 0.0;
      result.calibration_failure_rs0_std_ohm = measured ? tel.calibration_rs0_std_ohm : 0.0;
      result.calibration_failure_events = measured ? tel.calibration_events : 0;
      result.calibration_events_wanted = controller_config.drive.calibration_events;
      result.calibration_failure_detail =
          tel.calibration_failure == core::CalibrationFailure::kRsOutsideWindow
              ? rs_outside_window_text(controller_config.drive, tel.calibration_rs0_ohm, tel.calibration_rs0_std_ohm)
              : std::string();
      const bool refused_before_it_ran = core::refused_on_request(tel.calibration_failure);
      result.calibration_failure_winding_rise_C =
          core::refused_on_winding_rise(tel.calibration_failure) ? tel.calibration_winding_rise_C : 0.0;
      result.calibration_failure_pairs = refused_before_it_ran
                                             ? core::OutcomeCounts{}  // refused before it ran: another run's
                                             : tel.calibration_outcomes;
      result.calibration_failure_aborts = refused_before_it_ran ? core::AbortCounts{} : tel.calibration_aborts;
      if (options.log_events) {
        calibration_line =
            refused_before_it_ran
                ? fmt::format("{:10.3f}  calibration refused: {}", t, core::calibration_failure_name(tel.calibration_failure))
                : fmt::format("{:10.3f}  calibration failed: {}{}", t,
                              core::calibration_failure_name(tel.calibration_failure),
                              calibration_pairs_text(controller_config.drive.estimator, tel.calibration_outcomes,
                                                     tel.calibration_aborts));
      }
      calibration_ended = !refused_before_it_ran;  // a refusal leaves the event under way alone
    }
    if (step.calibration_to_store) {
      if (options.log_events) {
        calibration_line = fmt::format("{:10.3f}  calibration: Rs0 {:.5f} ohm at {:.1f} C{}{}{}", t,
                                       step.calibration_to_store->rs0_ohm, step.calibration_to_store->t0_C,
                                       t0_rise_text(*step.calibration_to_store),
                                       calibration_events_text(tel.calibration_events, controller_config.drive.calibration_events),
                                       calibration_pairs_text(controller_config.drive.estimator, tel.calibration_outcomes,
                                                              tel.calibration_aborts));
      }
      calibration_ended = true;
      result.calibrated = true;
      result.calibration = *step.calibration_to_store;
      result.magnet_reference_time_s = -1.0;  // a Ke0 taken after an earlier calibration is no more
      result.calibration_rs0_std_ohm = tel.calibration_rs0_std_ohm;
      result.calibration_events = tel.calibration_events;
      result.calibration_events_wanted = controller_config.drive.calibration_events;
      result.calibration_time_s = t;
      metrics_from_s = t;
      if (!scenario.controller.calibration_file.empty()) {
        try {
          write_calibration_file(scenario.controller.calibration_file, result.calibration,
                                 scenario.source.filename().string());
          result.calibration_stored = true;
        } catch (const CalibrationFileError& e) {
          result.calibration_file_error = e.what();
        }
      }
    }
    if (step.magnet_reference_to_store) {
      const core::Calibration& c = *step.magnet_reference_to_store;
      result.calibration.ke0_V_s_per_rad = c.ke0_V_s_per_rad;
      result.calibration.ke0_std_V_s_per_rad = c.ke0_std_V_s_per_rad;
      result.magnet_reference_time_s = t;
      result.magnet_reference_events = tel.magnet_reference_events;
      result.magnet_reference_at_C = tel.magnet_reference_at_C;
      result.magnet_reference_std_C = tel.magnet_reference_std_C;
      if (options.log_events) {
        calibration_line = fmt::format("{:10.3f}  magnet reference: Ke0 {:.4f} +- {:.4f} V s/rad at {:.1f} C, from {} "
                                       "turning events, the rotor taken at {:.1f} +- {:.1f} C",
                                       t, c.ke0_V_s_per_rad, c.ke0_std_V_s_per_rad, c.t0_C, tel.magnet_reference_events,
                                       tel.magnet_reference_at_C, tel.magnet_reference_std_C);
      }
      if (!scenario.controller.calibration_file.empty()) {
        try {
          write_calibration_file(scenario.controller.calibration_file, c, scenario.source.filename().string());
          result.calibration_stored = true;
        } catch (const CalibrationFileError& e) {
          result.calibration_file_error = e.what();
        }
      }
    }
    if (metrics_from_s < 0.0 && tel.calibration_failed) {
      // The method could not calibrate: count from here on the stored (nameplate) values.
      metrics_from_s = t;
    }
    if (drive.last_pair()) {
      const core::PairResult& p = *drive.last_pair();
      ++result.pairs[static_cast<std::size_t>(p.outcome)];
      ++event_pairs[static_cast<std::size_t>(p.outcome)];
      ++event_aborts[static_cast<std::size_t>(p.abort_cause)];  // (kNone: not aborted; as the drive's tally)
      if (p.outcome == core::PairOutcome::kAccepted && p.field_weakening) {
        ++result.field_weakening_pairs_accepted;
      }
      if (p.conditions.any_voltage_limited) {
        ++result.pairs_on_voltage_limit;
      }
    }
    if (drive.last_event() && drive.last_event()->outcome != core::EventOutcome::kPublished) {
      ++result.events_without_estimate[static_cast<std::size_t>(drive.last_event()->outcome)];
      if (options.log_events) {
        // The event's own pairs by outcome (what ended each: the guard that rejected it, the
        // hold that aborted it); the joint fit's figures where it had pairs to fit.
        const core::EventEstimate& e = *drive.last_event();
        result.event_log.push_back(
            e.pairs > 0
                ? fmt::format("{:10.3f}  event without estimate: {}; its pairs: {} (joint rs {:.2f} mOhm, vx {:.3f} V, ident {:.3f})",
                              t, core::to_string(e.outcome), core::pair_outcomes_text(event_pairs, event_aborts), 1e3 * e.rs_ohm,
                              e.joint_vx_V, e.joint_condition)
                : fmt::format("{:10.3f}  event without estimate: {}; its pairs: {}", t, core::to_string(e.outcome),
                              core::pair_outcomes_text(event_pairs, event_aborts)));
      }
    }
    // After this step's pair and event: the calibration's line, and a fresh tally where an event
    // may have been dropped without an estimate (a calibration's start or end sets the
    // scheduler's configuration, which drops the event under way).
    if (!calibration_line.empty()) {
      result.event_log.push_back(std::move(calibration_line));
      calibration_line.clear();
    }
    const bool calibration_started = tel.calibrating && !was_calibrating;
    was_calibrating = tel.calibrating;
    if (drive.last_event() || calibration_ended || calibration_started) {
      event_pairs = {};
      event_aborts = {};
    }
    calibration_ended = false;
    if (drive.last_estimate()) {
      const core::ResistanceEstimate& e = *drive.last_estimate();
      EstimateRow row;
      row.time_s = t;
      // The age is taken on the drive's clock, the truth looked up on the plant's: the two run
      // at one rate (parse_scenario requires the drive's period to be the plant's PWM period)
      // and may differ by an offset. `truth` is the plant's state at the sample this step
      // consumed (the plant steps after the drive, below), at plant.time_s().
      row.age_s = std::max(0.0, e.time_s - e.measured_at_s);
      const TruthHistory::Point then = history.at(plant.time_s() - row.age_s);
      row.rs_est_ohm = e.rs_ohm;
      row.rs_std_ohm = e.rs_std_ohm;
      row.rs_true_ohm = then.rs_ohm;
      row.winding_est_C = e.winding_C;
      row.winding_true_C = then.winding_C;
      row.vx_V = e.vx_V;
      row.vx_std_V = e.vx_std_V;
      row.lq_H = e.lq_H;
      row.vx_learning = e.vx_learning;
      row.bus_spread_V = e.bus_spread_V;
      row.vx_refused_bus_spread = e.vx_refused_bus_spread;
      row.joint_rs_ohm = e.joint_rs_ohm;
      row.joint_vx_V = e.joint_vx_V;
      row.speed_rad_s = truth.omega_m_rad_s;
      row.iq_A = tel.i_A.q;
      row.fused = e.fused;
      if (options.keep_estimates) {
        result.estimates.push_back(row);
      }
      (e.fused ? result.estimates_accepted : result.estimates_gated) += 1;
      if (std::isfinite(then.rs_ohm)) {
        sq_rs += std::pow(e.rs_ohm - then.rs_ohm, 2);
        ++rs_compared;
        if (e.fused && then.rs_ohm > 0.0) {
          rel_rs_sum += e.rs_ohm / then.rs_ohm - 1.0;
          ++rel_rs_count;
        }
      }
    }

    // The injection's own copper loss: 3/2 Rs |i_injection|^2, the winding's Rs (a motor
    // cable's loss heats the cable, not the machine).
    const double inj_sq = tel.injection_A.d * tel.injection_A.d + tel.injection_A.q * tel.injection_A.q;
    const double winding_rs_ohm = truth.rs_ohm - scenario.plant.motor.cable_at_C(truth.ambient_C);
    injection_energy_J += 1.5 * winding_rs_ohm * inj_sq * ts;
    injection_periods += tel.injection_active ? 1U : 0U;
    const bool counted = metrics_from_s >= 0.0 && t >= metrics_from_s;
    if (const std::optional<FastRow> row = run.accumulate(k, truth, tel.injection_active, counted); row && twin) {
      twin_link->row(k, *row, twin->twin_row(run, *row));
    }

    if (log_now) {
      SeriesRow row;
      row.time_s = t;
      row.winding_true_C = truth.winding_temp_C;
      row.winding_est_valid = tel.thermal_valid;
      row.winding_est_C = tel.thermal.winding_C;
      row.winding_std_C = tel.thermal.winding_std_C;
      row.magnet_true_C = truth.magnet_temp_C;
      row.magnet_est_C = tel.magnet_C;
      row.magnet_std_C = tel.magnet_std_C;
      row.magnet_valid = tel.magnet_valid;
      row.housing_true_C = truth.housing_temp_C;
      row.housing_est_C = tel.thermal.housing_C;
      row.missing_loss_W = tel.thermal.missing_loss_W;
      row.loss_scale_error = tel.thermal.loss_scale_error;
      row.cooling_scale_error = tel.thermal.cooling_scale_error;
      row.rs_true_ohm = truth.rs_ohm;
      row.speed_ref_rad_s = cmd.speed_ref_rad_s;
      row.speed_rad_s = truth.omega_m_rad_s;
      row.torque_Nm = truth.torque_em_Nm;
      row.load_torque_Nm = truth.load_torque_Nm;
      row.dc_bus_V = truth.dc_bus_V;
      row.current_valid = node.supervisor().status().sample_usable;
      row.id_A = tel.i_A.d;
      row.iq_A = tel.i_A.q;
      row.current_limit_A = tel.current_limit_A;
      row.derating = tel.derating;
      row.time_to_limit_valid = tel.time_to_limit_valid;
      row.time_to_limit_s = tel.time_to_limit_s;
      row.injection_active = tel.injection_active;
      if (metrics_from_s < 0.0 && !sc.calibrate && row.winding_est_valid &&
          (tel.estimates_published > 0 || scenario.controller.drive.estimator != core::EstimatorKind::kInjection ||
           scenario.controller.drive.injection.method == core::InjectionMethod::kNone)) {
        // Without a calibration run the figures start at the first estimate (a model-only
        // drive: at its first output), not at a guess the drive itself calls uncertain.
        metrics_from_s = t;
      }
      row.counted = row.winding_est_valid && metrics_from_s >= 0.0 && t >= metrics_from_s &&
                    truth.winding_temp_C > sc.error_threshold_C;
      if (row.counted) {
        const double err = row.winding_est_C - row.winding_true_C;
        sq_err += err * err;
        sum_err += err;
        covered += std::abs(err) <= 2.0 * row.winding_std_C ? 1U : 0U;
        band_sum_C += 2.0 * row.winding_std_C;
        result.band_2sigma_max_C = std::max(result.band_2sigma_max_C, 2.0 * row.winding_std_C);
        result.winding_error_max_C = std::max(result.winding_error_max_C, std::abs(err));
        ++result.winding_error_samples;
        if (row.magnet_valid) {
          const double magnet_err = row.magnet_est_C - row.magnet_true_C;
          sq_magnet += magnet_err * magnet_err;
          result.magnet_error_max_C = std::max(result.magnet_error_max_C, std::abs(magnet_err));
          magnet_covered += std::abs(magnet_err) <= 2.0 * row.magnet_std_C ? 1U : 0U;
          ++result.magnet_error_samples;
        }
      }
      result.max_winding_true_C = std::max(result.max_winding_true_C, truth.winding_temp_C);
      if (options.keep_series) {
        result.series.push_back(row);
      }
    }

    run.finish(step);

    if (tty && (k & 0x3FFF) == 0) {
      const auto now = std::chrono::steady_clock::now();
      if (now - last_progress > std::chrono::milliseconds(250)) {
        last_progress = now;
        const double wall = std::chrono::duration<double>(now - wall_start).count();
        std::fprintf(stderr, "\r  %s: %5.1f %%  %.1f of %.1f s simulated, %.1fx real time   ", sc.name.c_str(),
                     100.0 * static_cast<double>(k) / static_cast<double>(periods), t, sc.duration_s, wall > 0 ? t / wall : 0.0);
      }
    }
  }
  if (tty) {
    std::fprintf(stderr, "\r%*s\r", 90, "");
  }

  result.sim_time_s = plant.time_s();
  for (std::size_t c = 0; c < core::kFaultCodeCount; ++c) {
    result.faults[c].count = node.supervisor().counts()[c];
  }
  result.wall_time_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - wall_start).count();
  if (twin_link) {
    const TwinStepper& stepper = twin_link->finish();
    result.twin_wall_time_s = stepper.wall_s();
    result.twin_sim_time_s = static_cast<double>(stepper.periods()) * ts;
  }
  result.magnet_rejected = drive.telemetry().magnet_rejected;
  result.magnet_last_refusal = drive.telemetry().magnet_last_refusal.reason;
  result.magnet_last_refused_C = drive.telemetry().magnet_last_refusal.reading_C;
  if (result.winding_error_samples > 0) {
    const auto n = static_cast<double>(result.winding_error_samples);
    result.winding_error_rms_C = std::sqrt(sq_err / n);
    result.winding_error_mean_C = sum_err / n;
    result.coverage_2sigma = static_cast<double>(covered) / n;
    result.band_2sigma_mean_C = band_sum_C / n;
  }
  if (result.magnet_error_samples > 0) {
    result.magnet_error_rms_C = std::sqrt(sq_magnet / static_cast<double>(result.magnet_error_samples));
    result.magnet_coverage_2sigma =
        static_cast<double>(magnet_covered) / static_cast<double>(result.magnet_error_samples);
  }
  if (rs_compared > 0) {
    result.rs_error_rms_mohm = 1e3 * std::sqrt(sq_rs / static_cast<double>(rs_compared));
  } else if (result.estimates_published() > 0) {
    result.rs_error_rms_mohm = kNan;  // published, but none within the truth's history
  }
  if (rel_rs_count > 0) {
    result.rs_error_mean_pct = 100.0 * rel_rs_sum / static_cast<double>(rel_rs_count);
  }
  if (result.calibrated) {
    // The plant's law at the calibration's temperature.
    const double truth_rs0 =
        scenario.plant.motor.rs_at_C(result.calibration.t0_C) + scenario.plant.motor.cable_at_C(result.calibration.t0_C);
    if (truth_rs0 > 0.0) {
      result.calibration_rs0_error_pct = 100.0 * (result.calibration.rs0_ohm / truth_rs0 - 1.0);
    }
    // Eq. 3's form: pole pairs times the flux linkage, at t0_C by the plant's linear law.
    const plant::MotorConfig& m = scenario.plant.motor;
    const double truth_ke0 = m.pole_pairs * plant::psi_m_from_Ke(m.ke_V_s_per_rad, m.pole_pairs) *
                             (1.0 + m.magnet_temp_coefficient_per_C * (result.calibration.t0_C - m.magnet_ref_temp_C));
    if (result.calibration.ke0_V_s_per_rad > 0.0 && truth_ke0 > 0.0) {
      result.calibration_ke0_error_pct = 100.0 * (result.calibration.ke0_V_s_per_rad / truth_ke0 - 1.0);
    }
  }
  result.injection_loss_W = result.sim_time_s > 0.0 ? injection_energy_J / result.sim_time_s : 0.0;
  result.injection_duty = periods > 0 ? static_cast<double>(injection_periods) / static_cast<double>(periods) : 0.0;
  result.angle_correction_rad = drive.angle_correction_rad();
  result.calibration_running_at_end = drive.telemetry().calibrating;
  result.vx_V = drive.telemetry().vx_V;
  result.vx_std_V = drive.telemetry().vx_std_V;
  result.vx_bus_slope = drive.telemetry().vx_bus_slope;
  result.vx_bus_slope_std = drive.telemetry().vx_bus_slope_std;
  result.bus_slope_error = drive.bus_slope_error();
  result.bus_slope_error_std = drive.bus_slope_error_std();
  result.lq_H = drive.telemetry().lq_H;
  result.lq_std_H = drive.telemetry().lq_std_H;
  result.lq_saturation_H = drive.telemetry().lq_saturation_H;
  result.lq_bend_H = drive.telemetry().lq_bend_H;
  result.lq_listening_pairs = drive.telemetry().lq_listening_pairs;
  result.lq_listening_learned = drive.telemetry().lq_listening_learned;
  result.lq_emf_d_Wb = drive.telemetry().lq_emf_d_Wb;
  result.lq_emf_d_std_Wb = drive.telemetry().lq_emf_d_std_Wb;
  result.flux_linkage_Wb = scenario.controller.drive.injection.flux_linkage_Wb;
  result.lq_saturation_resolved = drive.telemetry().lq_saturation_resolved;
  result.estimates_dropped_at_restart = drive.telemetry().estimates_dropped_at_restart;
  result.lq_commissioned_saturation_H = core::commissioned_lq_saturation_H(scenario.controller.drive.injection);

  return result;
}

}  // namespace

SimulationResult run_scenario(const Scenario& given, const RunOptions& options) {
  // A stored calibration replaces the configured one before the drive starts, as in the daemon.
  const auto wall_start = std::chrono::steady_clock::now();
  auto wall_s = [&] { return std::chrono::duration<double>(std::chrono::steady_clock::now() - wall_start).count(); };
  Scenario scenario = given;
  const StoredCalibration stored = load_stored_calibration(scenario.controller);
  const core::DriveConfig& d = scenario.controller.drive;
  const bool injects = d.estimator == core::EstimatorKind::kInjection && d.injection.method != core::InjectionMethod::kNone;
  const bool with_twin = injects && options.twin_for_disturbance;
  const ScenarioConfig& sc = scenario.scenario;
  const auto after = static_cast<std::size_t>(std::llround(sc.disturbance_window_s / (d.period_s * kFastEvery)));
  DisturbanceMeter meter(after, d.motor.rated_speed_rad_s, sc.rated_torque_Nm);
  SimulationResult result = run_once(scenario, options, with_twin ? &meter : nullptr);
  result.calibration_file = scenario.controller.calibration_file;
  result.calibration_at_start = stored;
  if (!with_twin) {
    result.wall_time_s = wall_s();
    return result;
  }
  const Disturbance& speed = meter.speed();
  const Disturbance& torque = meter.torque();
  result.disturbance_measured = true;
  // A figure without a row to judge (an injection that never pauses leaves no row away from it)
  // is none: NaN here, null in the JSON, a dash in the tables.
  constexpr double kNone = std::numeric_limits<double>::quiet_NaN();
  const bool during = speed.during_rows > 0;
  const bool outside = speed.outside_rows > 0;
  result.speed_disturbance_pct = during ? 100.0 * speed.during : kNone;
  result.speed_disturbance_at_s = during ? static_cast<double>(speed.during_row * kFastEvery) * d.period_s : kNone;
  result.torque_disturbance_at_s = during ? static_cast<double>(torque.during_row * kFastEvery) * d.period_s : kNone;
  result.speed_difference_outside_pct = outside ? 100.0 * speed.outside : kNone;
  result.torque_disturbance_pct = during ? 100.0 * torque.during : kNone;
  result.speed_disturbance_mean_pct = during ? 100.0 * speed.during_sum / static_cast<double>(speed.during_rows) : kNone;
  result.torque_disturbance_mean_pct = during ? 100.0 * torque.during_sum / static_cast<double>(torque.during_rows) : kNone;
  result.torque_difference_outside_pct = outside ? 100.0 * torque.outside : kNone;
  // Everything the scenario cost: the run, its twin and the metrics.
  result.wall_time_s = wall_s();
  return result;
}

std::string result_json(const SimulationResult& r) {
  JsonWriter j;
  j.begin_object()
      .field("scenario", r.scenario)
      .field("method", r.method)
      .field("winding_error_rms_C", r.winding_error_samples > 0 ? r.winding_error_rms_C : kNan)
      .field("winding_error_max_C", r.winding_error_samples > 0 ? r.winding_error_max_C : kNan)
      .field("winding_error_mean_C", r.winding_error_samples > 0 ? r.winding_error_mean_C : kNan)
      .field("winding_error_samples", static_cast<std::uint64_t>(r.winding_error_samples))
      .field("coverage_2sigma", r.winding_error_samples > 0 ? r.coverage_2sigma : kNan)
      .field("band_2sigma_mean_C", r.winding_error_samples > 0 ? r.band_2sigma_mean_C : kNan)
      .field("band_2sigma_max_C", r.winding_error_samples > 0 ? r.band_2sigma_max_C : kNan)
      .field("rs_error_rms_mohm", r.estimates_published() == 0 ? kNan : r.rs_error_rms_mohm)
      .field("rs_error_mean_pct", r.rs_error_mean_pct)
      .field("magnet_error_rms_C", r.magnet_error_samples > 0 ? r.magnet_error_rms_C : kNan)
      .field("magnet_error_max_C", r.magnet_error_samples > 0 ? r.magnet_error_max_C : kNan)
      .field("magnet_coverage_2sigma", r.magnet_error_samples > 0 ? r.magnet_coverage_2sigma : kNan)
      .field("magnet_rejected", static_cast<std::uint64_t>(r.magnet_rejected))
      .field("estimates_accepted", static_cast<std::uint64_t>(r.estimates_accepted))
      .field("estimates_gated", static_cast<std::uint64_t>(r.estimates_gated))
      .field("estimates_dropped_at_restart", static_cast<std::uint64_t>(r.estimates_dropped_at_restart));
  std::uint64_t rejected = 0;
  for (std::size_t k = 1; k < r.pairs.size(); ++k) {
    rejected += r.pairs[k];
  }
  j.field("pairs_rejected", rejected);
  j.field("estimates_rejected", rejected);  // its former name (it counts pairs): kept for the scripts that read it
  j.key("pairs").begin_object();
  for (std::size_t k = 0; k < r.pairs.size(); ++k) {
    j.field(core::to_string(static_cast<core::PairOutcome>(k)), static_cast<std::uint64_t>(r.pairs[k]));
  }
  j.end_object();
  j.field("field_weakening_pairs", static_cast<std::uint64_t>(r.field_weakening_pairs_accepted));
  j.field("pairs_on_voltage_limit", static_cast<std::uint64_t>(r.pairs_on_voltage_limit));
  j.field("speed_disturbance_pct", r.disturbance_measured ? r.speed_disturbance_pct : kNan)
      .field("torque_disturbance_pct", r.disturbance_measured ? r.torque_disturbance_pct : kNan)
      .field("speed_disturbance_mean_pct", r.disturbance_measured ? r.speed_disturbance_mean_pct : kNan)
      .field("torque_disturbance_mean_pct", r.disturbance_measured ? r.torque_disturbance_mean_pct : kNan)
      .field("speed_disturbance_at_s", r.disturbance_measured ? r.speed_disturbance_at_s : kNan)
      .field("torque_disturbance_at_s", r.disturbance_measured ? r.torque_disturbance_at_s : kNan)
      .field("speed_difference_outside_injection_pct", r.disturbance_measured ? r.speed_difference_outside_pct : kNan)
      .field("torque_difference_outside_injection_pct", r.disturbance_measured ? r.torque_difference_outside_pct : kNan)
      .field("injection_loss_W", r.injection_loss_W)
      .field("injection_duty", r.injection_duty)
      .field("calibrated", r.calibrated)
      .field("calibration_running_at_end", r.calibration_running_at_end);
  if (r.calibrated) {
    j.key("calibration")
        .begin_object()
        .field("time_s", r.calibration_time_s)
        .field("rs0_ohm", r.calibration.rs0_ohm)
        .field("rs0_std_ohm", r.calibration_rs0_std_ohm)
        .field("events", r.calibration_events)
        .field("rs0_error_pct", r.calibration_rs0_error_pct)
        .field("ke0_error_pct", r.calibration_ke0_error_pct)
        .field("t0_C", r.calibration.t0_C)
        .field("t0_rise_std_C", r.calibration.t0_rise_std_C)
        .field("ke0_V_s_per_rad", r.calibration.ke0_V_s_per_rad)
        .field("ke0_std_V_s_per_rad", r.calibration.ke0_std_V_s_per_rad > 0.0 ? r.calibration.ke0_std_V_s_per_rad : kNan)
        .field("dead_time_band_A", r.calibration.dead_time_band_A > 0.0 ? r.calibration.dead_time_band_A : kNan)
        .field("vx_V", r.calibration.vx_std_V > 0.0 ? r.calibration.vx_V : kNan)
        .field("vx_std_V", r.calibration.vx_std_V > 0.0 ? r.calibration.vx_std_V : kNan)
        .field("vx_bus_V", r.calibration.vx_std_V > 0.0 && r.calibration.vx_bus_V > 0.0 ? r.calibration.vx_bus_V : kNan)
        .field("angle_correction_rad", r.calibration.angle_correction_measured ? r.calibration.angle_correction_rad : kNan)
        .field("ke0_from_turning_s", r.magnet_reference_time_s >= 0.0 ? r.magnet_reference_time_s : kNan)
        .field("ke0_rotor_C", r.magnet_reference_time_s >= 0.0 ? r.magnet_reference_at_C : kNan)
        .field("ke0_rotor_std_C", r.magnet_reference_time_s >= 0.0 ? r.magnet_reference_std_C : kNan)
        .field("ke0_events", r.magnet_reference_time_s >= 0.0 ? r.magnet_reference_events : 0)
        .end_object();
  }
  if (r.calibration_failure != core::CalibrationFailure::kNone) {
    // The failures that measured an Rs0 and refused it.
    const bool measured_rs0 = core::refused_measured_rs0(r.calibration_failure);
    j.key("calibration_failure")
        .begin_object()
        .field("time_s", r.calibration_failure_time_s)
        .field("reason", core::calibration_failure_name(r.calibration_failure))
        .field("rs0_ohm", measured_rs0 ? r.calibration_failure_rs0_ohm : kNan)
        .field("rs0_std_ohm", measured_rs0 ? r.calibration_failure_rs0_std_ohm : kNan)
        .field("events", measured_rs0 ? r.calibration_failure_events : 0)
        .field("winding_rise_C", core::refused_on_winding_rise(r.calibration_failure) ? r.calibration_failure_winding_rise_C : kNan)
        .key("pairs")
        .begin_object();
    for (std::size_t k = 0; k < r.calibration_failure_pairs.size(); ++k) {
      j.field(core::to_string(static_cast<core::PairOutcome>(k)), static_cast<std::uint64_t>(r.calibration_failure_pairs[k]));
    }
    j.end_object().key("aborted_by").begin_object();
    for (std::size_t k = 1; k < r.calibration_failure_aborts.size(); ++k) {
      j.field(core::to_string(static_cast<core::AbortCause>(k)), static_cast<std::uint64_t>(r.calibration_failure_aborts[k]));
    }
    j.end_object().end_object();
  }
  // Every fault the drive latched, by name (an empty object: none).
  j.key("faults").begin_object();
  for (const SimulationResult::FaultSeen& f : r.faults) {
    if (f.count > 0) {
      j.key(core::to_string(r.fault_code(f)))
          .begin_object()
          .field("count", static_cast<std::uint64_t>(f.count))
          .field("first_s", f.first_s)
          .end_object();
    }
  }
  j.end_object();
  // The levels those faults trip at: the scenario's [supervisor] keys over the daemon's defaults
  // for its drive, so that a report says which trips the run was judged by.
  const core::SupervisorConfig& s = r.supervisor;
  j.key("supervisor")
      .begin_object()
      .field("dc_bus_min_V", s.dc_bus_min_V)
      .field("dc_bus_max_V", s.dc_bus_max_V)
      .field("overcurrent_A", s.overcurrent_A)
      .field("max_speed_rad_s", s.max_speed_rad_s)
      .field("overspeed_rad_s", s.overspeed_rad_s)
      .field("trip_temp_C", s.trip_temp_C)
      .field("ambient_min_C", s.ambient_min_C)
      .field("ambient_max_C", s.ambient_max_C)
      .end_object();
  if (r.inverter_sweep.outcome != core::InverterSweepOutcome::kNone) {
    const core::InverterSweepResult& w = r.inverter_sweep;
    const bool fitted = w.fitted;
    j.key("inverter_sweep")
        .begin_object()
        .field("time_s", r.inverter_sweep_time_s)
        .field("outcome", std::string(core::to_string(w.outcome)))
        .field("vx_V", fitted ? w.vx_V : kNan)
        .field("vx_std_V", fitted ? w.vx_std_V : kNan)
        .field("band_A", fitted ? w.band_A : kNan)
        .field("rs_ohm", fitted ? w.rs_ohm : kNan)
        .field("offset_V", fitted ? w.offset_V : kNan)
        .field("residual_rms_V", fitted ? w.residual_rms_V : kNan)
        .end_object();
  }
  if (r.angle_check.outcome != core::AngleCheckOutcome::kNone) {
    const core::AngleCheckResult& a = r.angle_check;
    const bool solved = a.outcome == core::AngleCheckOutcome::kMeasured || a.outcome == core::AngleCheckOutcome::kOutOfRange ||
                        a.outcome == core::AngleCheckOutcome::kUnsteady;
    j.key("angle_check")
        .begin_object()
        .field("time_s", r.angle_check_time_s)
        .field("outcome", std::string(core::to_string(a.outcome)))
        .field("offset_rad", solved ? a.offset_rad : kNan)
        .field("offset_std_rad", solved ? a.offset_std_rad : kNan)
        .field("model_std_rad", solved ? a.model_std_rad : kNan)
        .field("speed_std_rad", solved ? a.speed_std_rad : kNan)
        .field("d_id_A", solved ? a.d_id_A : kNan)
        .field("d_iq_A", solved ? a.d_iq_A : kNan)
        .end_object();
  }
  j.field("angle_correction_rad", r.angle_correction_rad);
  if (!r.calibration_file.empty()) {
    j.key("calibration_file")
        .begin_object()
        .field("path", r.calibration_file)
        .field("at_start", std::string(to_string(r.calibration_at_start)))
        .field("stored", r.calibration_stored);
    if (!r.calibration_file_error.empty()) {
      j.field("error", r.calibration_file_error);
    }
    j.end_object();
  }
  j.field("vx_V", r.vx_V)
      .field("vx_std_V", r.vx_std_V)
      .field("vx_bus_slope_V_per_V", r.vx_bus_slope)
      .field("vx_bus_slope_std_V_per_V", r.vx_bus_slope_std)
      .field("bus_slope_error_V_per_V", r.bus_slope_error)
      .field("bus_slope_error_std_V_per_V", r.bus_slope_error_std)
      .field("lq_H", r.lq_H)
      .field("lq_std_H", r.lq_std_H)
      .field("lq_saturation_H", r.lq_saturation_H)
      .field("lq_bend_H", r.lq_bend_H)
      .field("lq_listening_pairs", static_cast<std::uint64_t>(r.lq_listening_pairs))
      .field("lq_listening_learned", static_cast<std::uint64_t>(r.lq_listening_learned))
      .field("lq_emf_d_Wb", r.lq_emf_d_Wb)
      .field("lq_emf_d_std_Wb", r.lq_emf_d_std_Wb)
      .field("lq_saturation_resolved", r.lq_saturation_resolved)
      .field("lq_commissioned_saturation_H", r.lq_commissioned_saturation_H)
      .field("max_winding_true_C", r.max_winding_true_C)
      .field("sim_time_s", r.sim_time_s)
      .field("wall_time_s", r.wall_time_s)
      .field("twin_wall_time_s", r.twin_wall_time_s)
      .field("twin_sim_time_s", r.twin_sim_time_s)
      .field("sim_speed_ratio", r.wall_time_s > 0.0 ? r.sim_time_s / r.wall_time_s : kNan)
      .end_object();
  return j.str();
}

std::string result_text(const SimulationResult& r) {
  // The pairs that did not give a measurement, by what ended them ("18 rejected_speed_change, 1
  // aborted"): not all of them were rejected by a guard.
  core::OutcomeCounts others = r.pairs;
  others[static_cast<std::size_t>(core::PairOutcome::kAccepted)] = 0U;
  std::uint64_t not_accepted = 0;
  for (const std::uint32_t n : others) {
    not_accepted += n;
  }
  std::string out = fmt::format("{} — {}\n", r.scenario, r.method);
  if (r.winding_error_samples > 0) {
    out += fmt::format("  winding error (truth > {:.0f} C)    RMS {:.2f} C, max {:.2f} C, mean {:+.2f} C ({} samples)\n",
                       r.error_threshold_C, r.winding_error_rms_C, r.winding_error_max_C, r.winding_error_mean_C,
                       r.winding_error_samples);
    out += fmt::format("  truth inside the +-2 sigma band {:.1f} % of those samples (2 sigma: mean {:.2f} C, largest {:.2f} C)\n",
                       100.0 * r.coverage_2sigma, r.band_2sigma_mean_C, r.band_2sigma_max_C);
  } else if (r.calibration_running_at_end) {
    out += "  winding error                   none counted: the calibration had not finished when the run ended\n";
  } else {
    out += fmt::format("  winding error                   no samples with the truth above {:.0f} C after calibration\n",
                       r.error_threshold_C);
  }
  out += fmt::format("  true winding reached            {:.1f} C\n", r.max_winding_true_C);
  if (r.estimates_published() > 0) {
    out += std::isfinite(r.rs_error_rms_mohm)
               ? fmt::format("  Rs error (at their own time)    RMS {:.2f} mOhm\n", r.rs_error_rms_mohm)
               : std::string("  Rs error (at their own time)    none within the truth's record\n");
  }
  if (r.magnet_error_samples > 0) {
    out += fmt::format("  magnet error                    RMS {:.2f} C, max {:.2f} C, inside +-2 sigma {:.1f} %\n",
                       r.magnet_error_rms_C, r.magnet_error_max_C, 100.0 * r.magnet_coverage_2sigma);
  }
  if (r.magnet_rejected > 0) {
    out += fmt::format("  magnet measurements refused     {} (the last: {:.1f} C, {})\n", r.magnet_rejected,
                       r.magnet_last_refused_C, core::magnet_refusal_text(r.magnet_last_refusal));
  }
  const std::string fw = r.field_weakening_pairs_accepted > 0
                             ? fmt::format(" ({} field-weakening)", r.field_weakening_pairs_accepted)
                             : std::string{};
  const std::string on_limit = r.pairs_on_voltage_limit > 0
                                   ? fmt::format("; {} met the voltage limit", r.pairs_on_voltage_limit)
                                   : std::string{};
  out += fmt::format("  estimates                       {} fused, {} gated; pairs {} accepted{}, {} not{}{}\n",
                     r.estimates_accepted, r.estimates_gated, r.pairs[0], fw, not_accepted,
                     not_accepted > 0 ? " (" + core::pair_outcomes_text(others) + ")" : std::string{}, on_limit);
  if (r.disturbance_measured) {
    if (std::isfinite(r.speed_disturbance_pct)) {
      out += fmt::format("  disturbance by injection        speed {:.3f} % (at {:.2f} s), torque {:.2f} % of rated (at {:.2f} s), vs. the run without injection\n",
                         r.speed_disturbance_pct, r.speed_disturbance_at_s, r.torque_disturbance_pct, r.torque_disturbance_at_s);
    } else {
      out += "  disturbance by injection        none measured (no steady row within an injection's window)\n";
    }
    if (std::isfinite(r.speed_difference_outside_pct)) {
      out += fmt::format("  same difference outside         speed {:.3f} %, torque {:.2f} % of rated\n",
                         r.speed_difference_outside_pct, r.torque_difference_outside_pct);
    } else {
      out += "  same difference outside         none measured (the injection never paused long enough)\n";
    }
  }
  out += fmt::format("  injection loss                  {:.2f} W average ({:.1f} % of the time injecting)\n", r.injection_loss_W,
                     100.0 * r.injection_duty);
  if (r.angle_check.outcome != core::AngleCheckOutcome::kNone) {
    const core::AngleCheckResult& a = r.angle_check;
    out += fmt::format("  rotor-angle check at {:.2f} s     {}: offset {:+.3f} +- {:.3f} deg electrical (the speed's noise "
                       "+- {:.3f}; correction in use {:+.3f} deg)\n",
                       r.angle_check_time_s, core::to_string(a.outcome), a.offset_rad * 180.0 / std::numbers::pi,
                       a.offset_std_rad * 180.0 / std::numbers::pi, a.speed_std_rad * 180.0 / std::numbers::pi,
                       r.angle_correction_rad * 180.0 / std::numbers::pi);
  }
  if (r.inverter_sweep.outcome != core::InverterSweepOutcome::kNone) {
    const core::InverterSweepResult& w = r.inverter_sweep;
    if (w.fitted) {
      out += fmt::format("  inverter sweep at {:.2f} s        {}: Vx {:.4f} +- {:.4f} V, band {:.3f} A, Rs {:.5f} ohm, residual {:.4f} V\n",
                         r.inverter_sweep_time_s, core::to_string(w.outcome), w.vx_V, w.vx_std_V, w.band_A, w.rs_ohm,
                         w.residual_rms_V);
    } else {
      out += fmt::format("  inverter sweep at {:.2f} s        {}: no fit\n", r.inverter_sweep_time_s, core::to_string(w.outcome));
    }
  }
  if (r.calibrated) {
    out += fmt::format("  calibration at {:.2f} s           Rs0 {:.5f} +- {:.5f} ohm at {:.1f} C{}, {}{}\n",
                       r.calibration_time_s, r.calibration.rs0_ohm, r.calibration_rs0_std_ohm, r.calibration.t0_C,
                       t0_rise_text(r.calibration),
                       r.magnet_reference_time_s >= 0.0 ? std::string("no Ke0 (at rest)")
                                                        : fmt::format("Ke0 {:.4f} V s/rad", r.calibration.ke0_V_s_per_rad),
                       calibration_events_text(r.calibration_events, r.calibration_events_wanted));
    if (r.magnet_reference_time_s >= 0.0) {
      out += fmt::format("  magnet reference at {:.2f} s      Ke0 {:.4f} +- {:.4f} V s/rad from {} turning events (the rotor "
                         "taken at {:.1f} +- {:.1f} C; the calibration measured none)\n",
                         r.magnet_reference_time_s, r.calibration.ke0_V_s_per_rad, r.calibration.ke0_std_V_s_per_rad,
                         r.magnet_reference_events, r.magnet_reference_at_C, r.magnet_reference_std_C);
    }
  }
  if (r.calibration_failure == core::CalibrationFailure::kTimeout) {
    out += fmt::format("  calibration failed at {:.2f} s    timeout: fewer published events by calibration.timeout_s than "
                       "calibration.min_events{}; the calibration in use stays\n",
                       r.calibration_failure_time_s,
                       r.estimator == core::EstimatorKind::kInjection
                           ? " (its pairs: " + core::pair_outcomes_text(r.calibration_failure_pairs, r.calibration_failure_aborts) + ")"
                           : std::string{});
  } else if (r.calibration_failure == core::CalibrationFailure::kWindingWarm) {
    out += fmt::format("  calibration failed at {:.2f} s    winding_warm: the winding was {:.1f} C above the ambient sensor "
                       "({}); the calibration in use stays (a motor replaced or rewound since that "
                       "calibration reads warm through its Rs0 even when cold: give the winding's temperature with the "
                       "request, or remove the stored calibration)\n",
                       r.calibration_failure_time_s, r.calibration_failure_winding_rise_C, kWindingWarmMeasure);
  } else if (r.calibration_failure == core::CalibrationFailure::kAmbientHeld) {
    out += fmt::format("  calibration failed at {:.2f} s    ambient_held: the ambient sensor had stopped reporting, its last "
                       "reading held; the calibration in use stays\n",
                       r.calibration_failure_time_s);
  } else if (r.calibration_failure == core::CalibrationFailure::kTemperatureImplausible) {
    out += fmt::format("  calibration failed at {:.2f} s    temperature_implausible: the temperature given lies {:.1f} K from "
                       "the winding the drive had just measured (more than 4 sigma + calibration.max_winding_rise_C); the "
                       "calibration in use stays\n",
                       r.calibration_failure_time_s, std::abs(r.calibration_failure_winding_rise_C));
  } else if (r.calibration_failure == core::CalibrationFailure::kOvertemperatureLatched) {
    out += fmt::format("  calibration failed at {:.2f} s    overtemperature_latched: asked for with OVERTEMPERATURE latched; "
                       "the calibration in use stays\n",
                       r.calibration_failure_time_s);
  } else if (r.calibration_failure == core::CalibrationFailure::kRsOutsideWindow) {
    out += fmt::format("  calibration failed at {:.2f} s    rs_outside_window: {} The calibration in use stays\n",
                       r.calibration_failure_time_s, r.calibration_failure_detail);
  } else if (r.calibration_failure == core::CalibrationFailure::kUncertain) {
    const std::string cut_short = cut_short_calibration_text(r.calibration_failure_events, r.calibration_events_wanted,
                                                             r.calibration_failure_pairs, r.calibration_failure_aborts,
                                                             r.estimator);
    out += fmt::format("  calibration failed at {:.2f} s    uncertain: Rs0 {:.5f} +- {:.5f} ohm ({:.2f} %, above "
                       "calibration.max_rs0_std_fraction){} ({}); the calibration in use stays\n",
                       r.calibration_failure_time_s, r.calibration_failure_rs0_ohm, r.calibration_failure_rs0_std_ohm,
                       100.0 * r.calibration_failure_rs0_std_ohm / std::max(std::abs(r.calibration_failure_rs0_ohm), 1e-12),
                       cut_short, uncertain_calibration_advice(!cut_short.empty(), r.estimator));
  }
  for (const SimulationResult::FaultSeen& f : r.faults) {
    if (f.count > 0) {
      out += fmt::format("  fault {:<25} latched {} time(s), first at {:.3f} s (never cleared: the drive stays off)\n",
                         core::to_string(r.fault_code(f)), f.count, f.first_s);
    }
  }
  if (!r.calibration_file.empty()) {
    out += fmt::format("  calibration file                {} ({} at start{})\n", r.calibration_file, to_string(r.calibration_at_start),
                       r.calibration_stored ? ", replaced by this run's calibration" : "");
  }
  out += fmt::format("  inverter voltage error Vx       {:.3f} +- {:.3f} V\n", r.vx_V, r.vx_std_V);
  if (r.bus_slope_error_std > 0.0 && r.bus_slope_error_std < 0.9 * r.vx_bus_slope_std) {
    // Only where estimates under load, holding Vx away from where it was learned, taught the
    // filter the slope's error beyond what the events knew (docs/estimator.md section 4).
    out += fmt::format("  Vx's bus slope                  {:+.5f} +- {:.5f} V/V from the events that learned Vx; its error under "
                       "load {:+.5f} +- {:.5f} V/V, learned by the winding's filter\n",
                       r.vx_bus_slope, r.vx_bus_slope_std, r.bus_slope_error, r.bus_slope_error_std);
  }
  out += fmt::format("  learned Lq                      {:.3f} +- {:.3f} mH at zero current, {:.3f} mH at the current limit{}\n",
                     1e3 * r.lq_H, 1e3 * r.lq_std_H, 1e3 * (r.lq_H - r.lq_saturation_H - r.lq_bend_H),
                     r.lq_saturation_resolved ? std::string()
                     : r.lq_commissioned_saturation_H > 0.0
                         ? fmt::format(" (not resolved: incremental = secant less the commissioned gap, b0 {:.3f} mH)",
                                       1e3 * r.lq_commissioned_saturation_H)
                         : std::string(" (not resolved: incremental = secant)"));
  if (r.flux_linkage_Wb > 0.0) {
    out += fmt::format("  learned d-axis EMF share        {:.2f} +- {:.2f} mWb (a rotor angle {:+.3f} +- {:.3f} deg electrical off)\n",
                       1e3 * r.lq_emf_d_Wb, 1e3 * r.lq_emf_d_std_Wb, r.lq_emf_d_Wb / r.flux_linkage_Wb * 180.0 / std::numbers::pi,
                       r.lq_emf_d_std_Wb / r.flux_linkage_Wb * 180.0 / std::numbers::pi);
  }
  out += fmt::format("  simulated {:.1f} s in {:.1f} s ({:.1f}x real time{})\n", r.sim_time_s, r.wall_time_s,
                     r.wall_time_s > 0 ? r.sim_time_s / r.wall_time_s : 0.0,
                     r.twin_wall_time_s > 0 ? fmt::format("; the twin without injection ran {:.1f} s of it around the events, in {:.1f} s",
                                                          r.twin_sim_time_s, r.twin_wall_time_s)
                                            : std::string());
  return out;
}

std::string estimates_text(const SimulationResult& r) {
  // time_s is the publication; the truth (rs_true, winding_true, err) is the plant's at the
  // time the estimate belongs to, age_s before it. learn: "yes" where the event refined Vx,
  // "bus" where only the spread of its recordings' buses (bus_V, the largest less the smallest
  // recording's mean; 0 for an event that would not have learned anyway) kept it from that.
  std::string out =
      "    time_s  age_s  speed_rad_s   iq_A   rs_est_mohm  std_mohm  rs_true_mohm  err_mohm  winding_est_C  winding_true_C  "
      "vx_V   vx_std_V  learn  bus_V  joint_rs_mohm  joint_vx_V  lq_mH  fused\n";
  for (const EstimateRow& e : r.estimates) {
    out += fmt::format("{:10.3f} {:6.3f} {:12.1f} {:6.1f} {:13.2f} {:9.2f} {:13.2f} {:9.2f} {:14.1f} {:15.1f} {:6.3f} {:10.3f} {:6} {:6.2f} {:14.2f} {:11.3f} {:6.3f}  {}\n",
                       e.time_s, e.age_s, e.speed_rad_s, e.iq_A, 1e3 * e.rs_est_ohm, 1e3 * e.rs_std_ohm, 1e3 * e.rs_true_ohm,
                       1e3 * (e.rs_est_ohm - e.rs_true_ohm), e.winding_est_C, e.winding_true_C, e.vx_V, e.vx_std_V,
                       e.vx_learning ? "yes" : (e.vx_refused_bus_spread ? "bus" : "no"), e.bus_spread_V,
                       1e3 * e.joint_rs_ohm, e.joint_vx_V, 1e3 * e.lq_H, e.fused ? "yes" : "gated");
  }
  return out;
}

void write_series_csv(const SimulationResult& r, const std::string& path) {
  errno = 0;
  std::ofstream out(path);
  if (!out) {
    throw std::runtime_error("cannot write " + path + (errno != 0 ? std::string(" (") + std::strerror(errno) + ")" : ""));
  }
  out << "time_s,winding_true_C,winding_est_C,winding_std_C,magnet_true_C,magnet_est_C,magnet_valid,housing_true_C,"
         "rs_true_ohm,speed_ref_rad_s,speed_rad_s,torque_Nm,load_torque_Nm,id_A,iq_A,current_limit_A,derating,"
         "time_to_limit_s,injection_active,housing_est_C,missing_loss_W,loss_scale_error,magnet_std_C,dc_bus_V,"
         "cooling_scale_error\n";
  for (const SeriesRow& s : r.series) {
    out << fmt::format("{:.4f},{:.3f},{},{},{:.3f},{},{},{:.3f},{:.6f},{:.3f},{:.3f},{:.3f},{:.3f},{},{},{:.2f},{},{},{},{},{},{},{},{:.2f},{}\n",
                       s.time_s, s.winding_true_C, s.winding_est_valid ? fmt::format("{:.3f}", s.winding_est_C) : "",
                       s.winding_est_valid ? fmt::format("{:.3f}", s.winding_std_C) : "", s.magnet_true_C,
                       s.magnet_valid ? fmt::format("{:.3f}", s.magnet_est_C) : "", s.magnet_valid ? 1 : 0,
                       s.housing_true_C, s.rs_true_ohm, s.speed_ref_rad_s, s.speed_rad_s, s.torque_Nm, s.load_torque_Nm,
                       s.current_valid ? fmt::format("{:.3f}", s.id_A) : "",
                       s.current_valid ? fmt::format("{:.3f}", s.iq_A) : "", s.current_limit_A, s.derating ? 1 : 0,
                       s.time_to_limit_valid ? fmt::format("{:.1f}", s.time_to_limit_s) : "", s.injection_active ? 1 : 0,
                       s.winding_est_valid ? fmt::format("{:.3f}", s.housing_est_C) : "",
                       s.winding_est_valid ? fmt::format("{:.2f}", s.missing_loss_W) : "",
                       s.winding_est_valid ? fmt::format("{:.4f}", s.loss_scale_error) : "",
                       s.magnet_valid ? fmt::format("{:.3f}", s.magnet_std_C) : "", s.dc_bus_V,
                       s.winding_est_valid ? fmt::format("{:.4f}", s.cooling_scale_error) : "");
  }
  out.close();
  if (!out) {
    throw std::runtime_error("cannot write " + path + " (a full disk, or a device that takes nothing?)");
  }
}

// A text as a gnuplot string literal: single-quoted, where nothing is special but the quote
// itself (written twice). A control character (a newline would end the command, and what
// followed would run as gnuplot's, `system` included) becomes a space.
static std::string gnuplot_quoted(std::string_view text) {
  std::string out = "'";
  for (const char ch : text) {
    if (ch == '\'') {
      out += "''";
    } else if (static_cast<unsigned char>(ch) < 0x20 || ch == 0x7f) {
      out += ' ';
    } else {
      out += ch;
    }
  }
  return out + "'";
}

void write_plot(const SimulationResult& r, const std::string& path) {
  char data_path[] = "/tmp/pmsm-plot-XXXXXX";
  const int fd = mkstemp(data_path);
  if (fd < 0) {
    throw std::runtime_error("cannot create a temporary file for the plot data");
  }
  close(fd);
  char points_path[] = "/tmp/pmsm-plot-points-XXXXXX";
  const int fd2 = mkstemp(points_path);
  if (fd2 < 0) {
    std::remove(data_path);
    throw std::runtime_error("cannot create a temporary file for the plot data");
  }
  close(fd2);
  {
    std::ofstream data(data_path);
    for (const SeriesRow& s : r.series) {
      data << fmt::format("{:.4f} {:.3f} {} {} {:.3f} {} {:.3f} {:.3f} {:.3f}\n", s.time_s, s.winding_true_C,
                          s.winding_est_valid ? fmt::format("{:.3f}", s.winding_est_C) : "NaN",
                          s.winding_est_valid ? fmt::format("{:.3f}", s.winding_std_C) : "NaN", s.magnet_true_C,
                          s.magnet_valid ? fmt::format("{:.3f}", s.magnet_est_C) : "NaN", s.speed_rad_s, s.torque_Nm,
                          s.speed_ref_rad_s);
    }
    std::ofstream points(points_path);
    for (const EstimateRow& e : r.estimates) {
      // At the time the estimate belongs to, against the truth's curve there.
      points << fmt::format("{:.4f} {:.3f} {}\n", e.time_s - e.age_s, e.winding_est_C, e.fused ? 1 : 0);
    }
    data.close();
    points.close();
    if (!data || !points) {
      std::remove(data_path);
      std::remove(points_path);
      throw std::runtime_error(fmt::format("cannot write the plot's data to {} and {} (a full disk?)", data_path, points_path));
    }
  }
  const std::string title = r.scenario + " — " + r.method;
  std::string script = fmt::format(R"gp(set terminal pngcairo size 1280,860 font "DejaVu Sans,10"
set output {}
set multiplot layout 2,1 title {} font ",12"
set grid
set key left top
set ylabel "temperature (°C)"
set size 1,0.62
set origin 0,0.36
set xlabel ""
plot {} using 1:($3-2*$4):($3+2*$4) with filledcurves fc rgb "#cce0ff" fs solid 0.6 title "estimate ± 2σ", \
     '' using 1:2 with lines lw 2 lc rgb "#c00000" title "winding (true)", \
     '' using 1:3 with lines lw 1.5 lc rgb "#0050c0" title "winding (estimate)", \
     '' using 1:5 with lines lw 1.5 dt 2 lc rgb "#d08000" title "magnet (true)", \
     '' using 1:6 with lines lw 1.2 lc rgb "#008000" title "magnet (estimate)"{}
set size 1,0.34
set origin 0,0.0
set ylabel "speed (rad/s), torque (Nm)"
set xlabel "simulated time (s)"
plot {} using 1:7 with lines lw 1.2 lc rgb "#404040" title "speed (true)", \
     '' using 1:9 with lines lw 1 dt 3 lc rgb "#808080" title "speed set-point", \
     '' using 1:8 with lines lw 1 lc rgb "#8000a0" title "torque (true)"
unset multiplot
)gp",
                                   gnuplot_quoted(path), gnuplot_quoted(title), gnuplot_quoted(data_path),
                                   r.estimates.empty()
                                       ? std::string()
                                       : fmt::format(", \\\n     {} using 1:($3>0?$2:1/0) with points pt 7 ps 0.5 lc rgb \"#303030\" "
                                                     "title \"resistance estimates (Eq. 1)\"",
                                                     gnuplot_quoted(points_path)),
                                   gnuplot_quoted(data_path));
  FILE* gp = popen("gnuplot", "w");  // its own messages go to stderr, not into our stdout
  if (gp == nullptr) {
    std::remove(data_path);
    std::remove(points_path);
    throw std::runtime_error("--plot needs gnuplot (apt-get install gnuplot-nox)");
  }
  std::fputs(script.c_str(), gp);
  const int status = pclose(gp);
  std::remove(data_path);
  std::remove(points_path);
  if (status != 0) {
    throw std::runtime_error(fmt::format("gnuplot failed (status {}) writing {}; is gnuplot installed (apt-get install gnuplot-nox)?",
                                         status, path));
  }
}

}  // namespace pmsm::app
