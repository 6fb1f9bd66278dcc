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

 private:
  double current_lsb_A_;
  double dc_lsb_V_;
  int calibration_samples_;
  int collected_ = 0;
  bool calibrated_ = false;
  std::array<double, 3> sums_{};
  std::array<double, 3> offsets_A_{};
};

}  // namespace pmsm::app
