# Install rules and the CMake package `tofu` (find_package(tofu) -> tofu::api).
#
# Included from the top-level CMakeLists.txt after every target is defined. `cmake
# --install BUILD --prefix PREFIX` installs only what a user of tofu needs (never the
# static libraries of the layers, which tofu's binary has linked in):
#
#   PREFIX/bin/tofu                              the CLI
#   PREFIX/bin/tofu-estimator-host               when that target exists
#   PREFIX/include/tofu/api.h, plugin.h          the versioned plug-in API (header-only)
#   PREFIX/<libdir>/cmake/tofu/tofuConfig.cmake         package config (tofu_API_VERSION)
#   PREFIX/<libdir>/cmake/tofu/tofuConfigVersion.cmake  0.1.0, SameMinorVersion
#   PREFIX/<libdir>/cmake/tofu/tofuTargets*.cmake       tofu::api, tofu::tofu, ...
#
# <libdir> is GNUInstallDirs' CMAKE_INSTALL_LIBDIR ("lib", or "lib/<multiarch>" under
# /usr on Debian); find_package searches both. The package is not architecture
# independent on purpose: a plug-in shares C++ objects with tofu, so a 32-bit plug-in
# build must not pick up a 64-bit tofu.

include(GNUInstallDirs)
include(CMakePackageConfigHelpers)

# The API version, read from the header it is defined in, so that the package can never
# disagree with what a plug-in compiles against.
file(STRINGS "${PROJECT_SOURCE_DIR}/include/tofu/api.h" tofu_api_version_line
     REGEX "^#define[ \t]+TOFU_API_VERSION[ \t]+[0-9]+[ \t]*$")
if(NOT tofu_api_version_line MATCHES "TOFU_API_VERSION[ \t]+([0-9]+)")
  message(FATAL_ERROR "include/tofu/api.h: no `#define TOFU_API_VERSION <integer>` line")
endif()
set(TOFU_API_VERSION ${CMAKE_MATCH_1})
# Re-run the configuration when the header changes (the number is baked into the package).
set_property(DIRECTORY APPEND PROPERTY CMAKE_CONFIGURE_DEPENDS
             "${PROJECT_SOURCE_DIR}/include/tofu/api.h")

# The top-level INSTALL_INTERFACE of tofu_api is the relative "include", so the headers go
# there whatever CMAKE_INSTALL_INCLUDEDIR says.
set(TOFU_INSTALL_INCLUDEDIR include)
set(TOFU_INSTALL_BINDIR ${CMAKE_INSTALL_BINDIR})
set(TOFU_INSTALL_CMAKEDIR ${CMAKE_INSTALL_LIBDIR}/cmake/tofu)

# ---- programs. tofu links static layers and system shared libraries only; keep the link
# path of any non-system shared library (a MuJoCo outside /usr) in the installed RPATH.
set_target_properties(tofu PROPERTIES INSTALL_RPATH_USE_LINK_PATH TRUE EXPORT_NAME tofu)
set(tofu_installed_programs tofu)
if(TARGET tofu-estimator-host)
  set_target_properties(tofu-estimator-host PROPERTIES INSTALL_RPATH_USE_LINK_PATH TRUE
                        EXPORT_NAME estimator-host)
  list(APPEND tofu_installed_programs tofu-estimator-host)
endif()
install(TARGETS ${tofu_installed_programs} EXPORT tofuTargets
        RUNTIME DESTINATION ${TOFU_INSTALL_BINDIR})

# ---- the plug-in API: header-only INTERFACE target, exported as tofu::api.
set_target_properties(tofu_api PROPERTIES EXPORT_NAME api)
install(TARGETS tofu_api EXPORT tofuTargets)
install(DIRECTORY "${PROJECT_SOURCE_DIR}/include/tofu" DESTINATION ${TOFU_INSTALL_INCLUDEDIR}
        FILES_MATCHING PATTERN "*.h")

# ---- the package: targets, config, version.
install(EXPORT tofuTargets NAMESPACE tofu:: FILE tofuTargets.cmake
        DESTINATION ${TOFU_INSTALL_CMAKEDIR})
configure_package_config_file(
  "${PROJECT_SOURCE_DIR}/cmake/tofuConfig.cmake.in"
  "${PROJECT_BINARY_DIR}/cmake/tofuConfig.cmake"
  INSTALL_DESTINATION ${TOFU_INSTALL_CMAKEDIR}
  PATH_VARS TOFU_INSTALL_INCLUDEDIR TOFU_INSTALL_BINDIR)
# SameMinorVersion: 0.1.x releases keep the API; the API version itself is checked again
# when tofu loads a plug-in (tofu_plugin_api_version(), include/tofu/plugin.h).
write_basic_package_version_file(
  "${PROJECT_BINARY_DIR}/cmake/tofuConfigVersion.cmake"
  VERSION ${PROJECT_VERSION}
  COMPATIBILITY SameMinorVersion)
install(FILES "${PROJECT_BINARY_DIR}/cmake/tofuConfig.cmake"
              "${PROJECT_BINARY_DIR}/cmake/tofuConfigVersion.cmake"
        DESTINATION ${TOFU_INSTALL_CMAKEDIR})
