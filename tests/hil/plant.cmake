# The pmsm-plant process on a real (virtual) CAN bus, through scripts/vcan-env (label hil).
#
#   plant_command_sender   a stand-in controller for these tests (not the daemon)
#   plant_hil_smoke        tests/hil/plant_smoke.sh: lockstep run captured with candump and
#                          decoded frame by frame with the DBC (pmsm-thermal decode --strict)
#   plant_process_hil_tests  gtest: lockstep determinism, sequence handling and re-sends,
#                          real-time command timeout / late / missing accounting via
#                          PLANT_STATUS, error messages for a missing interface
add_executable(plant_command_sender ${CMAKE_CURRENT_LIST_DIR}/plant_command_sender.cpp)
pmsm_target_defaults(plant_command_sender)
target_link_libraries(plant_command_sender PRIVATE pmsm::protocol pmsm::hal pmsm::plant)

add_test(NAME plant_hil_smoke
  COMMAND ${PROJECT_SOURCE_DIR}/scripts/vcan-env -- ${CMAKE_CURRENT_LIST_DIR}/plant_smoke.sh ${PROJECT_BINARY_DIR})
set_tests_properties(plant_hil_smoke PROPERTIES
  LABELS hil TIMEOUT 120 ENVIRONMENT "VCAN_ENV_TIMEOUT=100"
  PASS_REGULAR_EXPRESSION "plant_smoke: PASS"
  FAIL_REGULAR_EXPRESSION "plant_smoke: FAIL")
if(PMSM_SANITIZE)
  # See pmsm_add_vcan_gtest: no ASan inside User-Mode Linux.
  set_tests_properties(plant_hil_smoke PROPERTIES SKIP_RETURN_CODE 77
    ENVIRONMENT "VCAN_ENV_TIMEOUT=100;VCAN_ENV_MODE=native")
endif()

pmsm_add_vcan_gtest(plant_process_hil_tests
  SOURCES ${CMAKE_CURRENT_LIST_DIR}/plant_process_hil_test.cpp
  LIBS pmsm::protocol pmsm::hal
  TIMEOUT 240)
target_compile_definitions(plant_process_hil_tests PRIVATE PMSM_PLANT_EXE="$<TARGET_FILE:pmsm-plant>")
add_dependencies(plant_process_hil_tests pmsm-plant)
