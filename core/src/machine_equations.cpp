#include "pmsm/core/machine_equations.hpp"

namespace pmsm::core {

Dq rotor_frame_voltage(const DqMachine& m, const Dq& i_A, const Dq& di_dt_A_s,
                       double omega_e_rad_s, double omega_m_rad_s) {
  // Eq. 3: [vdr; vqr] = [Rs, -w Lq; w Ld, Rs] [idr; iqr] + [Ld 0; 0 Lq] d/dt [idr; iqr]
  //                      + [0; Ke wm]
  return {m.rs_ohm * i_A.d - omega_e_rad_s * m.lq_H * i_A.q + m.ld_H * di_dt_A_s.d,
          omega_e_rad_s * m.ld_H * i_A.d + m.rs_ohm * i_A.q + m.lq_H * di_dt_A_s.q +
              m.ke_V_s_per_rad * omega_m_rad_s};
}

}  // namespace pmsm::core
