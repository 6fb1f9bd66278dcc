// The boundary between the wire and the controller: ADC codes and encoder counts in, duty
// cycles out, with the controller's own (nominal) scaling and the current-ADC offset
// calibration every drive does at power-up with its gates off.
#pragma once

#include <array>
#include <cstdint>

#include "controller_config.hpp"
#include "pmsm/core/drive_controller.hpp"
#include "pmsm/hal/messages.hpp"

namespace pmsm::app {

class SensorFrontend {
 public:
  SensorFrontend(const SensorScaling& scaling, double period_s);

  // Converts one sample. While the offset calibration runs (the first offset_calibration_s
  // with the gates off), the codes are averaged and the input is marked not ready.
  [[nodiscard]] core::DriveInput convert(const hal::SensorSample& sample);

  // Duties and enable for the period after `sample`.
  [[nodiscard]] static hal::InverterCommand command(const core::DriveOutput& out, std::uint32_t sequence);

  [[nodiscard]] bool ready() const { return calibrated_; }
  [[nodiscard]] const std::array<double, 3>& offsets_A() const { return offsets_A_; }
  // The current samples' noise (standard deviation, A, the three phases' variances averaged):
  // sensors.current_noise_A when configured, else measured with the offsets (gates off, no
  // current flows: what varies is the sensor); 0 before that or without an offset calibration.
  [[nodiscard]] double current_noise_A() const { return noise_A_; }

 private:
  double current_lsb_A_;
  double dc_lsb_V_;
  int calibration_samples_;
  int collected_ = 0;
  bool calibrated_ = false;
  std::array<double, 3> sums_{};
  std::array<double, 3> squares_{};
  double noise_A_ = 0.0;
  bool noise_configured_ = false;
  std::array<double, 3> offsets_A_{};
};

}  // namespace pmsm::app
