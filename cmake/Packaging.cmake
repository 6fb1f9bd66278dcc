# The Debian package (`cpack -G DEB` in a build directory; tests/unit/package_deb.sh builds
# and checks it): the three programs, the systemd units and networkd/modules-load/sysusers
# files, the example configuration in /etc/pmsm-thermal as conffiles, the DBC and the plant
# profiles in /usr/share/pmsm-thermal. docs/deploy.md says how to install it and lists what
# lintian reports.
set(CPACK_GENERATOR DEB)
set(CPACK_PACKAGE_NAME pmsm-thermal)
set(CPACK_PACKAGE_VERSION ${PROJECT_VERSION})
set(CPACK_PACKAGE_DESCRIPTION_SUMMARY "PMSM drive controller that measures its winding temperature under load")
set(CPACK_PACKAGE_DESCRIPTION
  "pmsm-thermald runs the current loop of a permanent-magnet synchronous\nmotor and measures the stator resistance under load by windowed d-axis\ncurrent injection (Wilson, Stewart & Taylor, 2010), and so the winding\ntemperature, which it publishes on CAN. pmsm-plant emulates the motor,\ninverter and thermal network on a CAN bus; pmsm-thermal plans,\nsimulates, decodes and monitors.")
set(CPACK_PACKAGE_CONTACT "pmsm-thermal developers <pmsm-thermal@users.noreply.github.com>")
set(CPACK_PACKAGING_INSTALL_PREFIX /usr)
set(CPACK_STRIP_FILES ON)
set(CPACK_DEBIAN_FILE_NAME DEB-DEFAULT)
set(CPACK_DEBIAN_PACKAGE_SECTION electronics)
set(CPACK_DEBIAN_PACKAGE_PRIORITY optional)
# Library dependencies from the binaries themselves (dpkg-shlibdeps), as debhelper does.
set(CPACK_DEBIAN_PACKAGE_SHLIBDEPS ON)
set(CPACK_DEBIAN_PACKAGE_RECOMMENDS "can-utils, systemd")
set(CPACK_DEBIAN_PACKAGE_SUGGESTS "gnuplot-nox")
# conffiles: dpkg keeps a changed /etc/pmsm-thermal/*.toml across upgrades and asks.
# postinst: the system user (sysusers.d), a daemon-reload, and after an upgrade the running
# instances named (not restarted); prerm: on removal the running instances stopped; postrm: a
# daemon-reload, and on purge the instances' enable links removed.
configure_file(${CMAKE_CURRENT_LIST_DIR}/debian/conffiles ${CMAKE_BINARY_DIR}/debian/conffiles COPYONLY)
configure_file(${CMAKE_CURRENT_LIST_DIR}/debian/postinst ${CMAKE_BINARY_DIR}/debian/postinst COPYONLY)
configure_file(${CMAKE_CURRENT_LIST_DIR}/debian/prerm ${CMAKE_BINARY_DIR}/debian/prerm COPYONLY)
configure_file(${CMAKE_CURRENT_LIST_DIR}/debian/postrm ${CMAKE_BINARY_DIR}/debian/postrm COPYONLY)
set(CPACK_DEBIAN_PACKAGE_CONTROL_EXTRA
  ${CMAKE_BINARY_DIR}/debian/conffiles ${CMAKE_BINARY_DIR}/debian/postinst ${CMAKE_BINARY_DIR}/debian/prerm
  ${CMAKE_BINARY_DIR}/debian/postrm)
set(CPACK_DEBIAN_PACKAGE_CONTROL_STRICT_PERMISSION ON)
# A native package's changelog (lintian: no-changelog), compressed as Debian policy asks.
string(TIMESTAMP pmsm_changelog_date "%a, %d %b %Y %H:%M:%S +0000" UTC)
file(WRITE ${CMAKE_BINARY_DIR}/debian/changelog
  "pmsm-thermal (${PROJECT_VERSION}) unstable; urgency=medium\n\n"
  "  * Built from the pmsm-thermal sources; the history is the git log.\n\n"
  " -- ${CPACK_PACKAGE_CONTACT}  ${pmsm_changelog_date}\n")
execute_process(COMMAND gzip -9nc ${CMAKE_BINARY_DIR}/debian/changelog
  OUTPUT_FILE ${CMAKE_BINARY_DIR}/debian/changelog.gz COMMAND_ERROR_IS_FATAL ANY)
install(FILES ${CMAKE_BINARY_DIR}/debian/changelog.gz DESTINATION ${CMAKE_INSTALL_DOCDIR})
# The copyright file every package carries (lintian: no-copyright-file): the licence is not
# chosen yet, and the file says so.
install(FILES ${CMAKE_CURRENT_LIST_DIR}/debian/copyright DESTINATION ${CMAKE_INSTALL_DOCDIR})
include(CPack)
