# `pmsm-thermal decode` on the committed candump captures (label unit).
pmsm_add_gtest(cli_decode_test LABEL unit
  SOURCES ${CMAKE_CURRENT_LIST_DIR}/cli_decode_test.cpp
  LIBS pmsm::protocol_tools)
target_compile_definitions(cli_decode_test PRIVATE PMSM_THERMAL_EXE="$<TARGET_FILE:pmsm-thermal>")
add_dependencies(cli_decode_test pmsm-thermal)
# pmsm-thermal command's reading of the daemon's answers, on codec-built frames (label unit).
pmsm_add_gtest(cli_daemon_answers_test LABEL unit
  SOURCES ${CMAKE_CURRENT_LIST_DIR}/cli_daemon_answers_test.cpp
  LIBS pmsm::protocol_tools)
target_include_directories(cli_daemon_answers_test PRIVATE ${PROJECT_SOURCE_DIR}/tools/cli)
