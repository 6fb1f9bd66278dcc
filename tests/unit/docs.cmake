# The key tables of docs/configuration.md, docs/scenarios.md, docs/plant.md and docs/daemon.md
# match the schema that parses the files, and docs/cli.md's blocks every program's --help
# (scripts/update-docs regenerates them).
add_test(NAME docs_key_tables_current
  COMMAND ${PROJECT_SOURCE_DIR}/scripts/update-docs --check $<TARGET_FILE:pmsm-thermal> $<TARGET_FILE:pmsm-thermald>
          $<TARGET_FILE:pmsm-plant> $<TARGET_FILE:pmsm-dbc-gen>)
set_tests_properties(docs_key_tables_current PROPERTIES LABELS unit)
