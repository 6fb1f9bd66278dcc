# The bus side of pmsm-plant (PlantNode) on the in-process bus, and the process's command
# line (--check, configuration and bus errors). Label unit: no CAN needed.
pmsm_add_gtest(plant_node_test LABEL unit
  SOURCES ${CMAKE_CURRENT_LIST_DIR}/plant_node_test.cpp
  LIBS pmsm_plant_node)

pmsm_add_gtest(plant_cli_test LABEL unit
  SOURCES ${CMAKE_CURRENT_LIST_DIR}/plant_cli_test.cpp
  LIBS pmsm::plant)
target_compile_definitions(plant_cli_test PRIVATE PMSM_PLANT_EXE="$<TARGET_FILE:pmsm-plant>")
add_dependencies(plant_cli_test pmsm-plant)
