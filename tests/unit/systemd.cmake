# The units of systemd/ pass systemd-analyze verify (skipped, visibly, without it).
add_test(NAME systemd_units_verify
  COMMAND ${CMAKE_CURRENT_LIST_DIR}/systemd_verify.sh ${PROJECT_SOURCE_DIR}
          $<TARGET_FILE:pmsm-thermald> $<TARGET_FILE:pmsm-plant>)
set_tests_properties(systemd_units_verify PROPERTIES LABELS unit SKIP_RETURN_CODE 77)

# Every shipped daemon configuration passes pmsm-thermald --check; broken ones fail naming
# the key.
add_test(NAME daemon_config_check
  COMMAND ${CMAKE_CURRENT_LIST_DIR}/daemon_check.sh ${PROJECT_SOURCE_DIR} $<TARGET_FILE:pmsm-thermald>)
set_tests_properties(daemon_config_check PROPERTIES LABELS unit)
