# Estimator units of core/: pair recorder and fits (Section X), injection scheduler, thermal
# observer, angle tracker, no-injection baseline, dead-time compensation. Synthetic data
# from known parameters; fast (unit).
pmsm_add_gtest(estimator_unit_test LABEL unit
  SOURCES
    ${CMAKE_CURRENT_LIST_DIR}/estimator_pair_test.cpp
    ${CMAKE_CURRENT_LIST_DIR}/estimator_scheduler_test.cpp
    ${CMAKE_CURRENT_LIST_DIR}/estimator_thermal_test.cpp
    ${CMAKE_CURRENT_LIST_DIR}/estimator_angle_test.cpp
    ${CMAKE_CURRENT_LIST_DIR}/estimator_baseline_test.cpp
    ${CMAKE_CURRENT_LIST_DIR}/estimator_regression_test.cpp
    ${CMAKE_CURRENT_LIST_DIR}/estimator_inverter_sweep_test.cpp
    ${CMAKE_CURRENT_LIST_DIR}/estimator_angle_check_test.cpp
  LIBS pmsm::core)
