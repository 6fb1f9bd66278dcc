// Generated artefacts of the protocol definition (protocol.hpp): the DBC file and the frame
// tables of docs/protocol.md. Tests compare the committed files with these; regenerate with
//   pmsm-dbc-gen --dbc can/pmsm-thermal.dbc --docs docs/protocol.md
// (or `cmake --build <dir> --target pmsm-protocol-regen`).
#pragma once

#include <string>
#include <string_view>

#include "pmsm/hal/protocol.hpp"

namespace pmsm::hal::protocol {

// The DBC for one node (IDs = base + node). The committed can/pmsm-thermal.dbc is node 0.
[[nodiscard]] std::string generate_dbc(NodeId node = 0);

inline constexpr std::string_view kDocsBeginMarker =
    "<!-- BEGIN GENERATED: pmsm-dbc-gen --docs rewrites everything up to the END marker; do not edit by hand -->";
inline constexpr std::string_view kDocsEndMarker = "<!-- END GENERATED -->";

// The generated part of docs/protocol.md (ID map, every frame's signals, reject reasons),
// without the markers.
[[nodiscard]] std::string generate_docs_section();

// `document` with the text between the markers replaced by generate_docs_section().
// Throws std::runtime_error if the markers are missing or out of order.
[[nodiscard]] std::string update_docs(std::string_view document);

}  // namespace pmsm::hal::protocol
