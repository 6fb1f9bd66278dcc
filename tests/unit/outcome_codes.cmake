pmsm_add_gtest(outcome_codes_test LABEL unit
  SOURCES ${CMAKE_CURRENT_LIST_DIR}/outcome_codes_test.cpp
  LIBS pmsm::core pmsm::protocol)
