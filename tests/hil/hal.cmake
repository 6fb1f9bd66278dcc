# HIL tests of pmsm_hal on a real (virtual) CAN bus (pmsm_add_vcan_gtest: tests/CMakeLists.txt).
pmsm_add_vcan_gtest(hal_socketcan_hil_tests
  SOURCES ${CMAKE_CURRENT_LIST_DIR}/hal_socketcan_hil_test.cpp
  LIBS pmsm::hal
  TIMEOUT 300)

# The raw ping-pong benchmark, run briefly so that it cannot rot unnoticed.
if(PMSM_BUILD_BENCH)
  add_test(NAME hal_can_pingpong_smoke
    COMMAND ${PROJECT_SOURCE_DIR}/scripts/vcan-env -- $<TARGET_FILE:can_pingpong> --count 200)
  set_tests_properties(hal_can_pingpong_smoke PROPERTIES
    LABELS hil TIMEOUT 120 ENVIRONMENT "VCAN_ENV_TIMEOUT=100"
    PASS_REGULAR_EXPRESSION "\"median_rtt_us\"")
endif()
