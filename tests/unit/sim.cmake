pmsm_add_gtest(sim_truth_history_test LABEL unit
  SOURCES ${CMAKE_CURRENT_LIST_DIR}/sim_truth_history_test.cpp)
target_include_directories(sim_truth_history_test PRIVATE ${PROJECT_SOURCE_DIR}/tools/sim)
