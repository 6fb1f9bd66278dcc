# The shipped systemd units under a real systemd (tests/hil/systemd_units.sh): the host's
# systemd boots as PID 1 in User-Mode Linux on a copy-on-write overlay of the host's root,
# with the project installed into it; Type=notify, the watchdog restart, systemd-networkd's
# vcan0, sysusers, SCHED_FIFO under the unit's hardening, estimates on the bus.
if(PMSM_SANITIZE)
  # ASan cannot map its shadow memory inside User-Mode Linux, and this test has no native
  # variant (it needs a systemd of its own as PID 1): reported as skipped, never passed.
  add_test(NAME systemd_units_hil
    COMMAND sh -c "echo 'systemd_units: SKIP: sanitized binaries cannot run inside User-Mode Linux'; exit 77")
  set_tests_properties(systemd_units_hil PROPERTIES LABELS hil SKIP_RETURN_CODE 77)
else()
  add_test(NAME systemd_units_hil
    COMMAND ${CMAKE_CURRENT_LIST_DIR}/systemd_units.sh ${PROJECT_BINARY_DIR})
  set_tests_properties(systemd_units_hil PROPERTIES
    LABELS hil TIMEOUT 480 ENVIRONMENT "SYSTEMD_UNITS_TIMEOUT=420"
    SKIP_RETURN_CODE 77
    PASS_REGULAR_EXPRESSION "systemd_units: PASS"
    FAIL_REGULAR_EXPRESSION "systemd_units: FAIL")
endif()
