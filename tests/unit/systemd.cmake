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

# pmsm-thermal monitor on candump logs: the daemon's status frames, and commands checked.
add_test(NAME monitor_log
  COMMAND ${CMAKE_CURRENT_LIST_DIR}/monitor_log.sh ${PROJECT_SOURCE_DIR} $<TARGET_FILE:pmsm-thermal>)
set_tests_properties(monitor_log PROPERTIES LABELS unit)

# The Debian package: built with cpack, unpacked with dpkg-deb -x and checked (layout,
# conffiles, maintainer scripts, Depends, --version, the shipped configurations); lintian's
# findings printed. Needs the programs built, as every test does.
# The package is built from the builds that make its manual pages (not the sanitized ones).
if(NOT PMSM_SANITIZE AND NOT PMSM_FUZZ)
  add_test(NAME package_deb COMMAND ${CMAKE_CURRENT_LIST_DIR}/package_deb.sh ${PROJECT_BINARY_DIR} ${PROJECT_VERSION})
  set_tests_properties(package_deb PROPERTIES LABELS package SKIP_RETURN_CODE 77 TIMEOUT 300)
endif()
