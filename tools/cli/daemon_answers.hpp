// pmsm-thermal command's reading of what the daemon answers (THERMAL_ESTIMATE's calibration,
// RECEIVE_STATUS's rejections), apart from the command so that it is tested on frames alone.
#pragma once

#include <cstdint>
#include <cstdio>
#include <variant>

#include "pmsm/hal/codec.hpp"
#include "pmsm/hal/protocol.hpp"

namespace pmsm::app {

namespace protocol = hal::protocol;

// What the daemon says back, printed as it comes: a calibration's run and outcome (THERMAL_ESTIMATE's
// Calibrating and CalibrationResult) and the rejections of this node's commands that are not the
// synchronising frames' expected counter refusals (RECEIVE_STATUS: a bad CRC, a value out of
// range, a command held back while its stream was disturbed). Without it a refused or held-back
// request went unnoticed unless someone watched the bus. Counter refusals beyond this run's
// synchronising frames (one a stream it starts: `synchronising_frames`) are a second sender on
// this node's command streams: two supervisors interleaving their counters had most of their
// frames refused while each said all went out.
class DaemonAnswers {
 public:
  DaemonAnswers(int node, bool calibration_asked, std::FILE* out = stderr, int synchronising_frames = 1)
      : node_(node), calibration_asked_(calibration_asked), out_(out), counter_allowance_(synchronising_frames) {}

  void read(const hal::CanFrame& frame) {
    protocol::AnyDecoded d;
    if (protocol::decode_any(frame, d) != protocol::DecodeStatus::kOk || d.node != node_) {
      return;
    }
    if (const auto* t = std::get_if<protocol::ThermalEstimate>(&d.message)) {
      if (t->calibrating && !calibrating_) {
        calibration_seen_ = true;
        std::fprintf(out_, "pmsm-thermal command: node %d: calibration running\n", node_);
      } else if (!t->calibrating && calibrating_) {
        std::fprintf(out_, "pmsm-thermal command: node %d: calibration ended: %s\n", node_,
                     label(protocol::kCalibrationResultLabels, t->calibration_result));
        refused_ = refused_ || (calibration_asked_ && t->calibration_result != protocol::CalibrationResult::kDone);
      } else if (heard_estimate_ && t->calibration_result != result_ && !t->calibrating &&
                 t->calibration_result == protocol::CalibrationResult::kNone) {
        // NONE is "no calibration since this start": the daemon started again. Its result was
        // its run's, and what it stored stays in use; no refusal (it read as one: "calibration
        // NONE", exit 3, after a restart of a daemon whose calibration had ended DONE).
        std::fprintf(out_, "pmsm-thermal command: node %d: calibration result NONE again: the daemon started again (a "
                     "result is kept for the daemon's run; a stored calibration stays in use)\n", node_);
      } else if (heard_estimate_ && t->calibration_result != result_ && !t->calibrating) {
        calibration_seen_ = true;  // refused at once: it never ran
        std::fprintf(out_, "pmsm-thermal command: node %d: calibration %s\n", node_,
                     label(protocol::kCalibrationResultLabels, t->calibration_result));
        refused_ = refused_ || (calibration_asked_ && t->calibration_result != protocol::CalibrationResult::kDone);
      }
      calibrating_ = t->calibrating;
      result_ = t->calibration_result;
      heard_estimate_ = true;
    } else if (const auto* s = std::get_if<protocol::DriveStatus>(&d.message)) {
      // A fault or a disabled drive suspends a calibration (no pair runs with the gates off):
      // "running" alone would say it measures. Said once per suspension and cause.
      const char* why = !calibrating_                                 ? nullptr
                        : s->state == protocol::DriveState::kFault   ? "the drive is in FAULT (it resumes once the fault is cleared"
                        : s->state == protocol::DriveState::kStandby ? "the drive is not enabled (it resumes once it is"
                                                                     : nullptr;
      if (why != nullptr && why != suspended_why_) {
        std::fprintf(out_, "pmsm-thermal command: node %d: calibration suspended: %s, within calibration.timeout_s)\n", node_,
                     why);
      }
      suspended_why_ = why;
    } else if (const auto* h = std::get_if<protocol::Heartbeat>(&d.message)) {
      if (last_uptime_s_ >= 0.0 && h->uptime_s < last_uptime_s_) {
        // The daemon started again: what its first reports added was its counts starting over.
        counter_refusals_ = refusals_at_heartbeat_;
      } else {
        judge_counter_refusals();
      }
      refusals_at_heartbeat_ = counter_refusals_;
      last_uptime_s_ = h->uptime_s;
    } else if (const auto* r = std::get_if<protocol::ReceiveStatus>(&d.message)) {
      const std::uint64_t total = std::uint64_t{r->rejected_crc} + r->rejected_counter + r->rejected_range +
                                  r->rejected_format + r->rejected_other;
      const auto reason = static_cast<protocol::DecodeStatus>(r->last_rejection);
      const protocol::MessageDef* m = protocol::find_message(r->last_rejected_id);
      if (heard_status_ && total != total_ && m != nullptr && m->sender == protocol::Role::kSupervisor &&
          reason != protocol::DecodeStatus::kRepeatedCounter && reason != protocol::DecodeStatus::kCounterJump) {
        std::fprintf(out_, "pmsm-thermal command: node %d: the daemon rejected a %.*s (0x%03X): %s\n", node_,
                     static_cast<int>(m->name.size()), m->name.data(), r->last_rejected_id,
                     label(protocol::kDecodeStatusLabels, r->last_rejection));
        refused_ = true;
      }
      if (heard_status_) {
        // Each count is sent modulo 256 (RECEIVE_STATUS): the difference is taken the same way.
        // (A daemon started again counts from zero, which reads as refusals here: the next
        // HEARTBEAT tells, and takes them back.)
        counter_refusals_ += (r->rejected_counter - last_counter_count_) & 0xFFU;
      }
      last_counter_count_ = r->rejected_counter;
      total_ = total;
      heard_status_ = true;
    }
  }

  // A frame of this run's that did not go out (a full transmit queue): its counter was spent, so
  // the daemon may refuse the next one as a jump; that is this run's own, not another sender.
  void note_unsent_frame() { ++counter_allowance_; }

  // Whether the daemon refused something asked of it: a calibration that ended other than DONE
  // or was never seen, a command of this node rejected (not a synchronising frame's counter
  // refusal), counter refusals beyond those.
  [[nodiscard]] bool finish() {
    judge_counter_refusals();
    if (calibration_asked_ && !calibration_seen_) {
      std::fprintf(out_,
                   "pmsm-thermal command: node %d: no THERMAL_ESTIMATE showed the calibration asked for (the daemon's "
                   "log says why: a drive not running, a warm winding, a request lost)\n",
                   node_);
      return true;
    }
    return refused_;
  }

 private:
  template <class Table>
  static const char* label(const Table& table, auto value) {
    return protocol::label_of(table, static_cast<std::int64_t>(value)).data();  // string literals
  }

  // Counter refusals beyond the allowance, said once (judged at each HEARTBEAT that tells no
  // restart, and at the end).
  void judge_counter_refusals() {
    if (counter_refusals_ > static_cast<std::uint64_t>(counter_allowance_) && !clash_said_) {
      std::fprintf(out_,
                   "pmsm-thermal command: node %d: the daemon refused %llu command frame(s) of this node for their "
                   "alive counter, more than this run's %d synchronising or unsent frame(s): another supervisor is "
                   "sending to node %d (a command stream follows one sender's counter; docs/protocol.md)\n",
                   node_, static_cast<unsigned long long>(counter_refusals_), counter_allowance_, node_);
      clash_said_ = true;
      refused_ = true;
    }
  }

  int node_;
  bool calibration_asked_;
  std::FILE* out_;
  bool calibrating_ = false;
  bool calibration_seen_ = false;
  bool heard_estimate_ = false;
  protocol::CalibrationResult result_ = protocol::CalibrationResult::kNone;
  bool heard_status_ = false;
  std::uint64_t total_ = 0;  // RECEIVE_STATUS's rejection counts (each modulo 256), summed
  int counter_allowance_;
  std::uint64_t last_counter_count_ = 0;  // RejectedCounter as last heard (modulo 256)
  std::uint64_t counter_refusals_ = 0;    // since the first RECEIVE_STATUS heard
  bool clash_said_ = false;
  std::uint64_t refusals_at_heartbeat_ = 0;  // counter_refusals_ at the last HEARTBEAT
  double last_uptime_s_ = -1.0;              // its uptime (-1: none heard)
  bool refused_ = false;
  const char* suspended_why_ = nullptr;  // the cause last said (a string literal), or none
};

}  // namespace pmsm::app
