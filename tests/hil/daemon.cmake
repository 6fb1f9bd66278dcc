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

# Two plant/daemon pairs (AXES=4 by hand: docs/hil.md) on one bus under a flood of junk and malformed frames
# (tests/hil/daemon_axes_hil.sh): each estimate against its own plant, rejections counted by
# reason on the axis they were sent to and nowhere else, no lockstep period lost.
add_test(NAME daemon_axes_hil
  COMMAND ${PROJECT_SOURCE_DIR}/scripts/vcan-env -- ${CMAKE_CURRENT_LIST_DIR}/daemon_axes_hil.sh ${PROJECT_BINARY_DIR})
set_tests_properties(daemon_axes_hil PROPERTIES
  LABELS hil TIMEOUT 900 ENVIRONMENT "VCAN_ENV_TIMEOUT=870"
  SKIP_RETURN_CODE 77
  PASS_REGULAR_EXPRESSION "daemon_axes_hil: PASS"
  FAIL_REGULAR_EXPRESSION "daemon_axes_hil: FAIL")
if(PMSM_SANITIZE)
  set_tests_properties(daemon_axes_hil PROPERTIES ENVIRONMENT "VCAN_ENV_TIMEOUT=870;VCAN_ENV_MODE=native")
endif()
