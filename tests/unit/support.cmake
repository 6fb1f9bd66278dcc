# The test support code itself (tests/support).
pmsm_add_gtest(test_support_test LABEL unit
  SOURCES ${CMAKE_CURRENT_LIST_DIR}/test_support_test.cpp)
