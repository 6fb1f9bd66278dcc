// The calibration's result on disk: Rs0 and Ke0 at a known temperature T0 (Eq. 1), kept in a
// small TOML file so that a drive restarted warm does not have to recalibrate (it could not:
// the winding temperature is then unknown).
//
//   # pmsm-thermal calibration (Eq. 1: Rs = Rs0 (1 + alpha (T - T0)))
//   format = 1
//   rs0_ohm = 0.13231
//   t0_C = 25.0
//   ke0_V_s_per_rad = 0.9711
//   ke0_std_V_s_per_rad = 0.00021  (optional: Ke0's standard error)
//   vx_V = 7.49                     (optional, with vx_std_V: the bridge's voltage error
//   vx_std_V = 0.05                  Rs0 was learned with, and its standard error)
//   written_utc = "2026-11-21T10:00:00Z"
//   source = "reference-fm-bipolar.toml"
//   can_interface = "can0"          (optional, with can_node: the axis that wrote it,
//   can_node = 1                     StoredAxis)
//
// Written atomically: to a temporary file in the same directory, flushed to the device
// (fsync), renamed over the old file, and the directory flushed, so that a power cut leaves
// either the old calibration or the new one, never a torn file. Read strictly: every key
// checked, unknown keys and values out of range rejected with the file, line and key named.
#pragma once

#include <filesystem>
#include <stdexcept>
#include <string>
#include <string_view>

#include "pmsm/core/drive_controller.hpp"
#include "pmsm/core/thermal_observer.hpp"

namespace pmsm::app {

class CalibrationFileError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};
// The new file is in place, but its directory could not be flushed: a power loss may bring
// the old one back. Stored, not durable.
class CalibrationFileNotDurable : public CalibrationFileError {
 public:
  using CalibrationFileError::CalibrationFileError;
};

inline constexpr int kCalibrationFileFormat = 1;

// The axis a stored file belongs to, as pmsm-thermald writes it (its can.interface and can.node:
// keys can_interface and can_node, both or neither). A file is one axis's: a configuration
// copied for a second axis that still names the first one's file must not take the first
// motor's calibration or winding for its own. Not recorded (node -1): a file from before the
// keys, or written by another program (simulate, a hand edit), taken as any axis's.
struct StoredAxis {
  std::string can_interface;
  int can_node = -1;
  [[nodiscard]] bool recorded() const noexcept { return can_node >= 0; }
  [[nodiscard]] bool operator==(const StoredAxis&) const = default;
};
// Why a file of `stored`'s axis is not `mine`'s, or "" (the same axis, or not recorded).
[[nodiscard]] std::string other_axis_problem(const std::string& file, const StoredAxis& stored, const StoredAxis& mine,
                                             std::string_view key);

// Replaces `path` atomically with the calibration. Throws CalibrationFileError naming the
// path and the system's reason; the old file is then untouched and no temporary is left.
void write_calibration_file(const std::filesystem::path& path, const core::Calibration& calibration,
                            std::string_view source, const StoredAxis& axis = {});

// A calibration's Rs0 more than kRs0NameplateWarnFraction off what the configuration expects at
// its T0 (motor.rs_ohm by Eq. 1 and the configured conductor, plus motor.cable_resistance_ohm's
// cable): a warning that names the likely cause, a motor cable the configuration does not give
// or gives too small (docs/estimator.md section 6, "A motor cable"); empty when it is within
// that. For the drive's log when a calibration is done or loaded.
inline constexpr double kRs0NameplateWarnFraction = 0.10;
// A Ke0 further than this share from the motor's EMF constant (motor.ke_V_s_per_rad as phase
// peak per mechanical rad/s) is warned of: a magnet's temperature and a data sheet's tolerance
// do not explain it.
inline constexpr double kKe0OffMotorFraction = 0.30;
[[nodiscard]] std::string rs0_off_nameplate_warning(const core::DriveConfig& config, const core::Calibration& c);
// Why the calibration's Ke0 (stored, configured or just measured) lies more than
// kKe0OffMotorFraction from motor.ke_V_s_per_rad, or "": a motor.ke_V_s_per_rad entered wrong
// (the drive's EMF feed-forward and voltage limits use it; a measured Ke0 says which), another
// motor's calibration, or other units (a Ke0 per electrical rad/s is the motor's over its pole
// pairs). Every magnet reading is referred to Ke0.
[[nodiscard]] std::string ke0_off_motor_warning(const core::DriveConfig& config, const core::Calibration& c);

// Reads a calibration file (calibrated = true). Throws CalibrationFileError naming the file,
// line and key when it cannot be read or is not a valid calibration.
// `axis`, if given, receives the axis that wrote it (not recorded: node -1).
[[nodiscard]] core::Calibration read_calibration_file(const std::filesystem::path& path, StoredAxis* axis = nullptr);

// The thermal filter's state kept across a restart (a motor power-cycled warm), in the same
// atomic, strictly read TOML form:
//   # pmsm-thermal thermal state; replaced atomically by the drive
//   format = 1
//   winding_C = 92.4
//   housing_C = 71.0
//   winding_std_C = 1.3
//   ambient_C = 25.0
//   saved_unix_s = 1795493852.25
//   missing_loss_node = "housing" # where dP enters (absent: a file from when it was the winding's)
//   missing_loss_W = 4.2         # the loss model's errors the filter learned (dP, k, their
//   missing_loss_std_W = 21.0    # standard deviations and correlation): all five or none; a
//   loss_scale_error = 0.11      # file without them, or with a bad block of them, restarts
//   loss_scale_std = 0.05        # them from the priors (loss_errors_ignored says why) and
//   loss_correlation = -0.8      # keeps the temperatures; so does a block without
//                                #   missing_loss_node = "housing" (dP learned on the winding)
//   cooling_scale_error = 0.12   # the cooling path's error g and its deviation: both or neither;
//   cooling_scale_std = 0.08     #   without them, or with a bad pair, g restarts from its prior
//   can_interface = "can0"       # the axis that wrote it: its bus and node (both or neither; a
//   can_node = 1                 #   file without them is from before they were kept)
// The drive cools it through the downtime with its model (ThermalObserver::restore).
struct StoredThermalState {
  core::ThermalState state;
  double ambient_C = 25.0;
  double saved_unix_s = 0.0;  // CLOCK_REALTIME when it held
  // The axis that wrote it: a daemon does not take another axis's state, e.g. from a
  // configuration copied for a second axis whose thermal.state_file still names the first one's.
  StoredAxis axis;
  std::string loss_errors_ignored;  // why a loss-error block was not used (empty: used or absent)
  std::string cooling_error_ignored;  // why the cooling error's pair was not used (empty: used or absent)
};
// Refuses (CalibrationFileError, nothing written) to replace a file there that is no thermal
// state file (foreign_thermal_state_file).
void write_thermal_state_file(const std::filesystem::path& path, const StoredThermalState& stored);
// Why the file at `path` is not one the drive may replace with its thermal state, or "": none
// there, an empty one, or one that starts with the header the drive writes. Anything else
// (another axis's calibration, a log: a mistyped thermal.state_file) may be anything, and is
// not written over.
[[nodiscard]] std::string foreign_thermal_state_file(const std::filesystem::path& path);
// Refuses (CalibrationFileError) a file without the header the drive writes, as the write
// refuses to replace one.
[[nodiscard]] StoredThermalState read_thermal_state_file(const std::filesystem::path& path);

}  // namespace pmsm::app
