# The dependency arrows of docs/architecture.md: include lines (this test) and link lines
# (checked when CMake configures, below).
add_test(NAME architecture_dependencies
  COMMAND ${CMAKE_COMMAND} -DROOT=${PROJECT_SOURCE_DIR} -P ${PROJECT_SOURCE_DIR}/cmake/CheckArchitecture.cmake)
set_tests_properties(architecture_dependencies PROPERTIES LABELS unit)
