// toml++'s forward declarations (toml::table, toml::node, ...) for a header that only names
// them: the full <toml++/toml.h> costs every translation unit that includes it about 3 s of
// compile time (docs/performance.md, "Build time"). toml++ 3.3 (Debian 12) ships them as
// impl/forward_declarations.h, 3.4 and later as impl/forward_declarations.hpp; an unknown
// layout falls back to the whole library.
#pragma once

#if __has_include(<toml++/impl/forward_declarations.hpp>)
#include <toml++/impl/forward_declarations.hpp>
#elif __has_include(<toml++/impl/forward_declarations.h>)
#include <toml++/impl/forward_declarations.h>
#else
#include <toml++/toml.h>
#endif
