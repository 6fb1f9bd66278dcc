# pmsm-plant and pmsm-thermald as two processes on vcan (tests/hil/daemon_hil.sh): the heat-up
# judged from the bus, plant outage and recovery, daemon restart with the stored calibration.
add_test(NAME daemon_hil
  COMMAND ${PROJECT_SOURCE_DIR}/scripts/vcan-env -- ${CMAKE_CURRENT_LIST_DIR}/daemon_hil.sh ${PROJECT_BINARY_DIR})
set_tests_properties(daemon_hil PROPERTIES
  LABELS hil TIMEOUT 600 ENVIRONMENT "VCAN_ENV_TIMEOUT=570"
  PASS_REGULAR_EXPRESSION "daemon_hil: PASS"
  FAIL_REGULAR_EXPRESSION "daemon_hil: FAIL")
if(PMSM_SANITIZE)
  set_tests_properties(daemon_hil PROPERTIES SKIP_RETURN_CODE 77
    ENVIRONMENT "VCAN_ENV_TIMEOUT=570;VCAN_ENV_MODE=native")
endif()
