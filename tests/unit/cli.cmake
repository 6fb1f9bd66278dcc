pmsm_add_gtest(cli_plan_test LABEL unit
  SOURCES ${CMAKE_CURRENT_LIST_DIR}/cli_plan_test.cpp
  LIBS pmsm::core)
target_compile_definitions(cli_plan_test PRIVATE PMSM_THERMAL_EXE="$<TARGET_FILE:pmsm-thermal>"
                                                 PMSM_SOURCE_DIR="${PROJECT_SOURCE_DIR}")
add_dependencies(cli_plan_test pmsm-thermal)
