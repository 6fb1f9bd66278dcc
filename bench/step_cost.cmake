# pmsm_step_cost and bench/step-cost.sh: instructions per control step, by step class, counted
# by callgrind (deterministic, unlike a time on a shared machine). The ctest step_cost_budget
# fails when any step of a short replay exceeds the worst-case budget (docs/performance.md).
add_executable(pmsm_step_cost ${CMAKE_CURRENT_LIST_DIR}/step_cost.cpp)
pmsm_target_defaults(pmsm_step_cost)
target_compile_definitions(pmsm_step_cost PRIVATE PMSM_SOURCE_DIR="${PROJECT_SOURCE_DIR}")
target_include_directories(pmsm_step_cost PRIVATE ${CMAKE_CURRENT_LIST_DIR})
target_link_libraries(pmsm_step_cost PRIVATE pmsm_sim pmsm_drive pmsm::plant pmsm::core)

# The worst-case budget (issue: every step <= 20,000 instructions), on a short replay in which
# every kind of step happens. Deterministic instruction counts, never a time.
add_test(NAME step_cost_budget
  COMMAND ${CMAKE_CURRENT_LIST_DIR}/step-cost.sh ${PROJECT_BINARY_DIR} --budget 20000)
set_tests_properties(step_cost_budget PROPERTIES
  LABELS bench TIMEOUT 600 SKIP_RETURN_CODE 77
  # About 3 minutes under callgrind (a dump per step): COST makes a parallel ctest start it
  # first, beside the serial HIL tests, instead of last (a clean clone has no timing history).
  COST 1000
  PASS_REGULAR_EXPRESSION "step-cost: PASS"
  FAIL_REGULAR_EXPRESSION "step-cost: FAIL")
