# pmsm-thermald's loop and publisher against the plant node on the in-process bus.
pmsm_add_gtest(daemon_loop_test LABEL integration
  SOURCES ${CMAKE_CURRENT_LIST_DIR}/daemon_loop_test.cpp
  LIBS pmsm_daemon pmsm_plant_node pmsm_sim spdlog::spdlog
  TIMEOUT 600)

# Own binary: it replaces malloc and its family (tests/support/alloc_counter) to count allocations on the control thread.
pmsm_add_gtest(daemon_alloc_test LABEL integration
  SOURCES ${CMAKE_CURRENT_LIST_DIR}/daemon_alloc_test.cpp
  LIBS pmsm_daemon pmsm_plant_node pmsm_sim pmsm_test_alloc_counter
  TIMEOUT 400)

# The GPIO fault-input watcher (edge events, a failed read is a fault).
pmsm_add_gtest(daemon_fault_watch_test LABEL unit
  SOURCES ${PROJECT_SOURCE_DIR}/tests/unit/daemon_fault_watch_test.cpp
  LIBS pmsm_daemon)
