// pmsm-thermald's normal-priority side: drains the RT loop's publication records, encodes
// them with the protocol's codec and sends them on its own CAN endpoint (the user-facing
// frames: THERMAL_ESTIMATE, RESISTANCE_ESTIMATE, INJECTION_REPORT, DRIVE_STATUS, HEARTBEAT,
// FAULT, RECEIVE_STATUS, LOOP_TIMING), stores a completed calibration atomically, logs every fault change once, and
// reports the loop's counters (rejections by reason, deadline misses, timing) at most once a
// second and only when something changed. It also listens on its endpoint for this node's
// published identifiers: a frame there was sent by another device as this node (a second
// daemon configured with the same node id), which the drive answers with DUPLICATE_NODE.
#pragma once

#include <array>
#include <utility>
#include <chrono>
#include <cstdint>
#include <string>

#include "daemon_config.hpp"
#include "drive_loop.hpp"
#include "pmsm/hal/can_bus.hpp"

namespace pmsm::daemon {

struct PublisherStats {
  std::uint64_t frames_sent = 0;
  std::uint64_t frames_failed = 0;       // not sent (queue full, interface down, encode refused)
  std::uint64_t calibrations_stored = 0;
  std::uint64_t calibration_store_failures = 0;
  std::uint64_t thermal_states_stored = 0;
  std::uint64_t thermal_state_store_failures = 0;
  std::uint64_t reopens = 0;             // the publishing socket reopened after an interface loss
  std::uint64_t foreign_frames = 0;      // this node's published identifiers sent by another device
};

class Publisher {
 public:
  // How long DUPLICATE_NODE's cause outlives the other sender's last frame on this node's
  // identifiers: over two of its heartbeats (1 s), so that a daemon that publishes nothing
  // else keeps it.
  static constexpr std::chrono::milliseconds kDuplicateHold{2500};
  // A second source of this node's SENSOR_SAMPLE frames (a second free-running power stage
  // configured as this node): judged over windows of at least kSampleSourceWindow, heard when
  // samples older than the last one used came at kSecondSourceMinStale per kSampleSourceWindow or
  // more (100 a second, where a second stage sends thousands). A few stale frames (held up
  // somewhere) are not.
  static constexpr std::chrono::milliseconds kSampleSourceWindow{100};
  static constexpr std::uint64_t kSecondSourceMinStale = 10;

  // Installs the receive filters of this node's published identifiers on `bus` (the
  // publishing endpoint, which receives nothing else).
  Publisher(const DaemonConfig& config, hal::CanBus& bus, DriveLoop& loop);

  // One record from the ring (the drain thread).
  void handle(const PublicationRecord& record);
  // After each batch: another sender of this node's frames, the periodic report (the drain
  // thread).
  void after_batch();

  [[nodiscard]] const PublisherStats& stats() const noexcept { return stats_; }
  // Writes the thermal state file (the drain thread; at stop, after the control thread and the
  // drain thread have stopped: the final state).
  void store_thermal_state(const core::ThermalState& state, double ambient_C);
  // The summary line for the log at stop.
  [[nodiscard]] std::string summary() const;

 private:
  template <typename Message>
  void send(const Message& m);
  [[nodiscard]] std::string fault_cause(hal::protocol::FaultCode code, double value) const;
  void log_fault(const hal::protocol::FaultReport& f, const PublicationRecord& r);
  void log_refusals(const PublicationRecord& r);
  // Writes the calibration file (calibration.file), when there is one, and logs how that went.
  void store_calibration(const core::Calibration& c);
  void report();
  void send_receive_status(const LoopStats& s);
  void reopen_if_due();
  void watch_for_duplicates(std::chrono::steady_clock::time_point now);
  void watch_sample_sources(std::chrono::steady_clock::time_point now);

  const DaemonConfig& config_;
  hal::CanBus& bus_;
  DriveLoop& loop_;
  hal::protocol::NodeId node_;
  PublisherStats stats_{};
  std::uint32_t active_faults_ = 0;  // as last logged
  LoopStats last_{};
  std::chrono::steady_clock::time_point last_report_{};
  bool first_thermal_logged_ = false;
  unsigned salient_method_warned_ = 0;  // INJECTION_REPORT methods judged, one bit each
  // The INJECTION_REPORTs' results in the present window of kPairJudgedWindow judged pairs, by
  // outcome (the same numbering), until the pairs of a window are mostly rejected as speed or load
  // changes (app::pair_rejection_advice): said once.
  static constexpr std::uint32_t kPairJudgedWindow = 50;
  core::OutcomeCounts pair_results_{};
  std::uint32_t pair_window_judged_ = 0;
  bool pair_rejection_advised_ = false;
  bool ambient_held_ = false;  // as last logged
  std::uint32_t ambient_dropouts_ = 0;  // as last logged
  bool restore_shift_logged_ = false;
  std::uint32_t estimates_gated_logged_ = 0;  // the estimator's refusals as last logged
  std::uint32_t estimates_dropped_logged_ = 0;
  std::uint32_t magnet_rejected_logged_ = 0;
  std::uint64_t rejected_sent_ = 0;  // total rejections in the last RECEIVE_STATUS
  std::chrono::steady_clock::time_point receive_status_sent_{};
  std::chrono::steady_clock::time_point last_reopen_try_{};
  bool reopen_failure_logged_ = false;
  bool not_durable_logged_ = false;
  // One of DUPLICATE_NODE's causes: active from when it is heard until kDuplicateHold without.
  struct HeldCause {
    bool active = false;
    std::chrono::steady_clock::time_point heard{};
    // Heard at `now`; whether it became active.
    bool hear(std::chrono::steady_clock::time_point now) noexcept {
      heard = now;
      return !std::exchange(active, true);
    }
    // Whether it ends at `now`, quiet for kDuplicateHold.
    bool expire(std::chrono::steady_clock::time_point now) noexcept {
      if (active && now - heard >= kDuplicateHold) {
        active = false;
        return true;
      }
      return false;
    }
  };
  // DUPLICATE_NODE's causes: another sender of this node's published identifiers, or of its
  // SENSOR_SAMPLE frames.
  bool duplicate_ = false;  // the cause as handed to the loop: either
  HeldCause foreign_;
  std::uint32_t foreign_id_ = 0;  // the identifier it was last heard on
  std::chrono::steady_clock::time_point duplicates_watched_{};
  HeldCause second_source_;
  std::chrono::steady_clock::time_point sample_window_start_{};
  std::uint64_t stale_at_window_start_ = 0;
  std::uint64_t samples_at_window_start_ = 0;
};

}  // namespace pmsm::daemon
