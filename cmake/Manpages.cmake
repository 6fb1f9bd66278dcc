# Manual pages for the three programs, from their own --help and --version (help2man) plus a
# hand-written NAME, DESCRIPTION and SEE ALSO (cmake/man/*.h2m), gzipped as Debian policy
# asks, installed to man1 (pmsm-plant, pmsm-thermal) and man8 (pmsm-thermald, a daemon in
# sbin). Not in the sanitized builds: running their binaries at build time is not the point.
if(PMSM_SANITIZE OR PMSM_FUZZ)
  return()
endif()
find_program(HELP2MAN_EXECUTABLE help2man REQUIRED)  # scripts/setup-deps installs it
# The pages' date: SOURCE_DATE_EPOCH when the packager sets it, else the sources' last commit at
# configure time, so that two builds of one commit make the same pages (help2man reads it).
set(pmsm_man_epoch "$ENV{SOURCE_DATE_EPOCH}")
if(pmsm_man_epoch STREQUAL "")
  execute_process(COMMAND git -C ${PROJECT_SOURCE_DIR} log -1 --format=%ct
                  OUTPUT_VARIABLE pmsm_man_epoch OUTPUT_STRIP_TRAILING_WHITESPACE ERROR_QUIET)
endif()
set(pmsm_man_env)
if(pmsm_man_epoch MATCHES "^[0-9]+$")
  set(pmsm_man_env ${CMAKE_COMMAND} -E env SOURCE_DATE_EPOCH=${pmsm_man_epoch})
endif()
function(pmsm_man_page target section)
  set(include ${PROJECT_SOURCE_DIR}/cmake/man/${target}.h2m)
  set(page ${CMAKE_BINARY_DIR}/man/${target}.${section})
  add_custom_command(
    OUTPUT ${page}.gz
    COMMAND ${CMAKE_COMMAND} -E make_directory ${CMAKE_BINARY_DIR}/man
    COMMAND ${pmsm_man_env} ${HELP2MAN_EXECUTABLE} --no-info --no-discard-stderr --section=${section} --include=${include}
            --output=${page} $<TARGET_FILE:${target}>
    COMMAND gzip -9nf ${page}
    DEPENDS ${target} ${include}
    COMMENT "Manual page ${target}(${section})"
    VERBATIM)
  add_custom_target(${target}-man ALL DEPENDS ${page}.gz)
  install(FILES ${page}.gz DESTINATION ${CMAKE_INSTALL_MANDIR}/man${section})
endfunction()
pmsm_man_page(pmsm-thermald 8)
pmsm_man_page(pmsm-plant 1)
pmsm_man_page(pmsm-thermal 1)
