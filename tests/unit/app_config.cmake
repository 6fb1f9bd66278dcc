# Configuration of the applications: the TOML schema, the controller's configuration and the
# simulation scenarios (fixtures in data/config/). Fast (unit).
pmsm_add_gtest(app_config_test LABEL unit
  SOURCES
    ${CMAKE_CURRENT_LIST_DIR}/app_config_schema_test.cpp
    ${CMAKE_CURRENT_LIST_DIR}/app_config_controller_test.cpp
    ${CMAKE_CURRENT_LIST_DIR}/app_config_scenario_test.cpp
    ${CMAKE_CURRENT_LIST_DIR}/app_config_regression_test.cpp
    ${CMAKE_CURRENT_LIST_DIR}/app_calibration_file_test.cpp
  LIBS pmsm_drive pmsm_sim)

# Own binary: it replaces malloc and its family (tests/support/alloc_counter) to count allocations in the hot path.
pmsm_add_gtest(drive_alloc_test LABEL unit
  SOURCES ${CMAKE_CURRENT_LIST_DIR}/drive_alloc_test.cpp
  LIBS pmsm_drive pmsm::plant pmsm_test_alloc_counter)

# The drive node (the one per-sample path) against the plant library.
pmsm_add_gtest(drive_node_test LABEL unit
  SOURCES ${CMAKE_CURRENT_LIST_DIR}/drive_node_test.cpp
  LIBS pmsm_drive pmsm::plant)
