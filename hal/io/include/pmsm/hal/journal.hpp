// Whether the process's standard error is the systemd journal's stream.
#pragma once

namespace pmsm::hal {

// systemd's convention (systemd.exec(5), $JOURNAL_STREAM): a service whose stderr goes to the
// journal finds there "DEVICE:INODE" of that stream, and a program compares it with fstat() of
// its stderr. The variable alone is not enough: a child inherits it while writing to a terminal
// or a pipe (a --check run from a service's shell, `systemd-run --pty`, a provisioning script
// under systemd), and what it logs must then go where its stderr goes. $INVOCATION_ID says only
// that a unit runs the process, not where its stderr is connected.
[[nodiscard]] bool stderr_is_journal() noexcept;

}  // namespace pmsm::hal
