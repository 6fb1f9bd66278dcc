pmsm_add_gtest(estimator_closed_loop_test LABEL integration
  SOURCES ${CMAKE_CURRENT_LIST_DIR}/estimator_closed_loop_test.cpp
  LIBS pmsm_sim
  TIMEOUT 300)
target_compile_definitions(estimator_closed_loop_test PRIVATE PMSM_THERMAL_EXE="$<TARGET_FILE:pmsm-thermal>")
add_dependencies(estimator_closed_loop_test pmsm-thermal)

# The robustness suite's cases with bounds from the physics (bench/scenarios/robustness).
pmsm_add_gtest(estimator_robustness_test LABEL integration
  SOURCES ${CMAKE_CURRENT_LIST_DIR}/estimator_robustness_test.cpp
  LIBS pmsm_sim
  TIMEOUT 300)
