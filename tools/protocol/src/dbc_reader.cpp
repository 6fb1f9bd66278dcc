// DBC reader and generic decoder. Deliberately independent of protocol.hpp: it knows the
// DBC format, not our messages (see dbc.hpp).
#include "pmsm/tools/dbc.hpp"

#include "printable.hpp"
#include "text_file.hpp"

#include <algorithm>
#include <bit>
#include <cctype>
#include <charconv>
#include <cmath>
#include <cstdio>
#include <map>
#include <set>
#include <utility>

namespace pmsm::hal::dbc {

namespace {
std::string located(int line, const std::string& message, const std::string& file) {
  if (!file.empty()) {
    return line > 0 ? file + ":" + std::to_string(line) + ": " + message : file + ": " + message;
  }
  return line > 0 ? "line " + std::to_string(line) + ": " + message : message;
}
}  // namespace

ParseError::ParseError(int line, const std::string& message, const std::string& file)
    : std::runtime_error(located(line, message, file)), line_(line), message_(message) {}

namespace {

// The first element of `range` that satisfies `pred`, or nullptr.
template <typename Range, typename Pred>
auto find_first(const Range& range, Pred pred) noexcept -> decltype(&*std::ranges::begin(range)) {
  const auto it = std::ranges::find_if(range, pred);
  return it == std::ranges::end(range) ? nullptr : &*it;
}

}  // namespace

const ValueDescription* Signal::find_value(std::int64_t raw) const noexcept {
  return find_first(values, [raw](const ValueDescription& v) { return v.value == raw; });
}

const Signal* Message::find_signal(std::string_view signal_name) const noexcept {
  return find_first(signals, [signal_name](const Signal& s) { return s.name == signal_name; });
}

const Message* Database::find(std::uint32_t id, bool extended_id) const noexcept {
  return find_first(messages, [id, extended_id](const Message& m) { return m.id == id && m.extended == extended_id; });
}

const Message* Database::find(std::string_view message_name) const noexcept {
  return find_first(messages, [message_name](const Message& m) { return m.name == message_name; });
}

namespace {

// ---------------------------------------------------------------------------------------
// Tokenizer
// ---------------------------------------------------------------------------------------

enum class TokenKind : std::uint8_t { kIdentifier, kNumber, kString, kPunct, kEnd };

struct Token {
  TokenKind kind = TokenKind::kEnd;
  std::string text;  // strings: without quotes, escapes resolved
  int line = 0;
};

bool is_ident_start(char c) { return std::isalpha(static_cast<unsigned char>(c)) != 0 || c == '_'; }
bool is_ident_char(char c) { return std::isalnum(static_cast<unsigned char>(c)) != 0 || c == '_'; }
bool is_digit(char c) { return c >= '0' && c <= '9'; }

std::vector<Token> tokenize(std::string_view text) {
  std::vector<Token> tokens;
  int line = 1;
  std::size_t i = 0;
  const std::size_t n = text.size();
  while (i < n) {
    const char c = text[i];
    if (c == '\n') {
      ++line;
      ++i;
      continue;
    }
    if (c == ' ' || c == '\t' || c == '\r' || c == '\f' || c == '\v') {
      ++i;
      continue;
    }
    if (c == '/' && i + 1 < n && text[i + 1] == '/') {  // comment to the end of the line
      while (i < n && text[i] != '\n') {
        ++i;
      }
      continue;
    }
    Token t;
    t.line = line;
    if (c == '"') {
      t.kind = TokenKind::kString;
      ++i;
      bool closed = false;
      while (i < n) {
        const char d = text[i];
        if (d == '\\' && i + 1 < n && (text[i + 1] == '"' || text[i + 1] == '\\')) {
          t.text.push_back(text[i + 1]);
          i += 2;
          continue;
        }
        if (d == '"') {
          closed = true;
          ++i;
          break;
        }
        if (d == '\n') {
          ++line;
        }
        // A name, unit or value label is printed to a terminal (decode, monitor): no control
        // character but a comment's line breaks and tabs (an escape coloured decode's output).
        const auto u = static_cast<unsigned char>(d);
        const bool c1 = common::c1_control_at(text, i);
        if (((u < 0x20U && d != '\n' && d != '\r' && d != '\t') || u == 0x7fU || c1)) {
          char code[8];
          std::snprintf(code, sizeof code, "0x%02x", c1 ? static_cast<unsigned>(static_cast<unsigned char>(text[i + 1])) : u);
          throw ParseError(line, std::string("a control character (") + code + ") in a quoted string");
        }
        t.text.push_back(d);
        ++i;
      }
      if (!closed) {
        throw ParseError(t.line, "unterminated string");
      }
    } else if (is_digit(c) || ((c == '-' || c == '+') && i + 1 < n && (is_digit(text[i + 1]) || text[i + 1] == '.'))) {
      t.kind = TokenKind::kNumber;
      std::size_t j = i + 1;
      while (j < n && (is_digit(text[j]) || text[j] == '.')) {
        ++j;
      }
      if (j < n && (text[j] == 'e' || text[j] == 'E')) {
        std::size_t k = j + 1;
        if (k < n && (text[k] == '+' || text[k] == '-')) {
          ++k;
        }
        if (k < n && is_digit(text[k])) {
          j = k;
          while (j < n && is_digit(text[j])) {
            ++j;
          }
        }
      }
      // A number glued to letters (e.g. "12abc") is not a number.
      if (j < n && is_ident_char(text[j])) {
        throw ParseError(line, "malformed number '" + std::string(text.substr(i, j - i + 1)) + "'");
      }
      t.text = std::string(text.substr(i, j - i));
      i = j;
    } else if (is_ident_start(c)) {
      t.kind = TokenKind::kIdentifier;
      std::size_t j = i;
      while (j < n && is_ident_char(text[j])) {
        ++j;
      }
      t.text = std::string(text.substr(i, j - i));
      i = j;
    } else if (std::string_view(":|@()[],;+-").find(c) != std::string_view::npos) {
      t.kind = TokenKind::kPunct;
      t.text = std::string(1, c);
      ++i;
    } else {
      char buffer[64];
      std::snprintf(buffer, sizeof buffer, "unexpected character 0x%02X", static_cast<unsigned>(static_cast<unsigned char>(c)));
      throw ParseError(line, buffer);
    }
    tokens.push_back(std::move(t));
  }
  Token end;
  end.kind = TokenKind::kEnd;
  end.line = line;
  tokens.push_back(end);
  return tokens;
}

const std::set<std::string_view>& keywords() {
  static const std::set<std::string_view> k{
      "VERSION", "NS_", "NS_DESC_", "BS_", "BU_", "BO_", "SG_", "CM_", "BA_DEF_", "BA_DEF_DEF_", "BA_",
      "VAL_", "VAL_TABLE_", "SIG_VALTYPE_", "BO_TX_BU_", "EV_", "EV_DATA_", "ENVVAR_DATA_", "SGTYPE_",
      "SGTYPE_VAL_", "BA_DEF_SGTYPE_", "BA_SGTYPE_", "SIG_TYPE_REF_", "SIG_GROUP_", "SIGTYPE_VALTYPE_",
      "BA_DEF_REL_", "BA_REL_", "BA_DEF_DEF_REL_", "BU_SG_REL_", "BU_EV_REL_", "BU_BO_REL_",
      "SG_MUL_VAL_", "CAT_DEF_", "CAT_", "FILTER"};
  return k;
}

// Sections we accept and skip (to their ';').
const std::set<std::string_view>& skipped_sections() {
  static const std::set<std::string_view> k{
      "EV_", "EV_DATA_", "ENVVAR_DATA_", "SGTYPE_", "SGTYPE_VAL_", "BA_DEF_SGTYPE_", "BA_SGTYPE_",
      "SIG_TYPE_REF_", "SIG_GROUP_", "SIGTYPE_VALTYPE_", "BA_DEF_REL_", "BA_REL_", "BA_DEF_DEF_REL_",
      "BU_SG_REL_", "BU_EV_REL_", "BU_BO_REL_", "SG_MUL_VAL_", "CAT_DEF_", "CAT_", "FILTER", "NS_DESC_"};
  return k;
}

// ---------------------------------------------------------------------------------------
// Parser
// ---------------------------------------------------------------------------------------

struct AttributeDefinition {
  std::string object;  // "", "BU_", "BO_", "SG_", "EV_"
  std::string type;    // INT, HEX, FLOAT, STRING, ENUM
  std::vector<std::string> enum_values;
  std::optional<std::string> default_value;
};

// A reference to something inside a message, resolved after all messages are read.
struct PendingSignalRef {
  int line = 0;
  std::uint32_t dbc_id = 0;
  std::string signal;  // empty: the message itself
};

class Parser {
 public:
  explicit Parser(std::string_view text) : tokens_(tokenize(text)) {}

  Database run() {
    while (!at_end()) {
      statement();
    }
    resolve();
    return std::move(db_);
  }

 private:
  // --- token access -----------------------------------------------------------------------
  [[nodiscard]] const Token& peek(std::size_t ahead = 0) const {
    const std::size_t i = std::min(pos_ + ahead, tokens_.size() - 1);
    return tokens_[i];
  }
  [[nodiscard]] bool at_end() const { return peek().kind == TokenKind::kEnd; }
  const Token& next() {
    const Token& t = peek();
    if (pos_ < tokens_.size() - 1) {
      ++pos_;
    }
    return t;
  }
  [[nodiscard]] bool is_punct(char c, std::size_t ahead = 0) const {
    const Token& t = peek(ahead);
    return t.kind == TokenKind::kPunct && t.text.size() == 1 && t.text[0] == c;
  }
  [[nodiscard]] bool is_word(std::string_view w, std::size_t ahead = 0) const {
    const Token& t = peek(ahead);
    return t.kind == TokenKind::kIdentifier && t.text == w;
  }
  [[noreturn]] void fail(const Token& at, const std::string& message) const {
    throw ParseError(at.line, message);
  }
  static std::string describe(const Token& t) {
    switch (t.kind) {
      case TokenKind::kEnd: return "end of file";
      case TokenKind::kString: return "string \"" + t.text + "\"";
      default: return "'" + t.text + "'";
    }
  }
  void expect_punct(char c, std::string_view context) {
    if (!is_punct(c)) {
      fail(peek(), "expected '" + std::string(1, c) + "' " + std::string(context) + ", found " + describe(peek()));
    }
    next();
  }
  std::string expect_identifier(std::string_view what) {
    if (peek().kind != TokenKind::kIdentifier) {
      fail(peek(), "expected " + std::string(what) + ", found " + describe(peek()));
    }
    return next().text;
  }
  std::string expect_string(std::string_view what) {
    if (peek().kind != TokenKind::kString) {
      fail(peek(), "expected " + std::string(what) + " (a quoted string), found " + describe(peek()));
    }
    return next().text;
  }
  const Token& expect_number(std::string_view what) {
    if (peek().kind != TokenKind::kNumber) {
      fail(peek(), "expected " + std::string(what) + " (a number), found " + describe(peek()));
    }
    return next();
  }
  std::uint64_t expect_unsigned(std::string_view what) {
    const Token& t = expect_number(what);
    std::uint64_t value = 0;
    const char* first = t.text.data();
    const char* last = first + t.text.size();
    if (*first == '+') {
      ++first;
    }
    const auto [ptr, ec] = std::from_chars(first, last, value);
    if (ec != std::errc() || ptr != last) {
      fail(t, "expected " + std::string(what) + " (an unsigned integer), found '" + t.text + "'");
    }
    return value;
  }
  std::int64_t expect_integer(std::string_view what) {
    const Token& t = expect_number(what);
    std::int64_t value = 0;
    const char* first = t.text.data();
    const char* last = first + t.text.size();
    if (*first == '+') {
      ++first;
    }
    const auto [ptr, ec] = std::from_chars(first, last, value);
    if (ec != std::errc() || ptr != last) {
      fail(t, "expected " + std::string(what) + " (an integer), found '" + t.text + "'");
    }
    return value;
  }
  double expect_double(std::string_view what) {
    const Token& t = expect_number(what);
    return to_double(t, what);
  }
  double to_double(const Token& t, std::string_view what) const {
    double value = 0.0;
    const char* first = t.text.data();
    const char* last = first + t.text.size();
    if (*first == '+') {
      ++first;
    }
    const auto [ptr, ec] = std::from_chars(first, last, value);
    if (ec != std::errc() || ptr != last || !std::isfinite(value)) {
      fail(t, "expected " + std::string(what) + " (a number), found '" + t.text + "'");
    }
    return value;
  }
  void skip_to_semicolon(const Token& start) {
    while (!is_punct(';')) {
      if (at_end()) {
        fail(start, "missing ';' after " + start.text);
      }
      next();
    }
    next();
  }

  // --- statements ---------------------------------------------------------------------------
  void statement() {
    const Token& t = peek();
    if (t.kind != TokenKind::kIdentifier) {
      fail(t, "expected a DBC keyword, found " + describe(t));
    }
    const std::string keyword = t.text;
    const Token start = next();
    if (keyword == "VERSION") {
      db_.version = expect_string("version text");
    } else if (keyword == "NS_") {
      expect_punct(':', "after NS_");
      // The symbol list runs until the next section header ("BS_:", "BU_:" ...).
      while (!at_end() && !is_punct(':', 1)) {
        next();
      }
    } else if (keyword == "BS_") {
      expect_punct(':', "after BS_");
      // Optional "baudrate : btr1 , btr2" on the same line.
      while (!at_end() && peek().line == start.line) {
        next();
      }
    } else if (keyword == "BU_") {
      expect_punct(':', "after BU_");
      while (peek().kind == TokenKind::kIdentifier && keywords().count(peek().text) == 0) {
        db_.nodes.push_back(next().text);
      }
    } else if (keyword == "BO_") {
      message(start);
    } else if (keyword == "SG_") {
      signal(start);
    } else if (keyword == "CM_") {
      comment(start);
    } else if (keyword == "BA_DEF_") {
      attribute_definition(start);
    } else if (keyword == "BA_DEF_DEF_") {
      const std::string name = expect_string("attribute name");
      if (peek().kind != TokenKind::kNumber && peek().kind != TokenKind::kString) {
        fail(peek(), "expected a default value for attribute \"" + name + "\"");
      }
      pending_defaults_.emplace_back(name, next().text);
      expect_punct(';', "after BA_DEF_DEF_");
    } else if (keyword == "BA_") {
      attribute(start);
    } else if (keyword == "VAL_") {
      value_descriptions(start);
    } else if (keyword == "VAL_TABLE_") {
      expect_identifier("value table name");
      while (peek().kind == TokenKind::kNumber) {
        expect_integer("value");
        expect_string("value label");
      }
      expect_punct(';', "after VAL_TABLE_");
    } else if (keyword == "SIG_VALTYPE_") {
      PendingSignalRef ref{start.line, static_cast<std::uint32_t>(expect_unsigned("message id")), ""};
      ref.signal = expect_identifier("signal name");
      if (is_punct(':')) {
        next();
      }
      const std::int64_t type = expect_integer("signal value type");
      if (type < 0 || type > 2) {
        fail(start, "SIG_VALTYPE_ must be 0, 1 or 2");
      }
      expect_punct(';', "after SIG_VALTYPE_");
      value_types_.emplace_back(ref, type);
    } else if (keyword == "BO_TX_BU_") {
      PendingSignalRef ref{start.line, static_cast<std::uint32_t>(expect_unsigned("message id")), ""};
      expect_punct(':', "after the message id of BO_TX_BU_");
      std::vector<std::string> senders;
      while (peek().kind == TokenKind::kIdentifier) {
        senders.push_back(next().text);
        if (is_punct(',')) {
          next();
        }
      }
      expect_punct(';', "after BO_TX_BU_");
      extra_senders_.emplace_back(ref, std::move(senders));
    } else if (skipped_sections().count(keyword) != 0) {
      skip_to_semicolon(start);
    } else {
      fail(start, "unknown keyword '" + keyword + "'");
    }
  }

  void message(const Token& start) {
    Message m;
    const std::uint64_t dbc_id = expect_unsigned("message id");
    if (dbc_id > 0xFFFF'FFFFU) {
      fail(start, "message id out of range");
    }
    m.extended = (dbc_id & 0x8000'0000U) != 0U;
    m.id = static_cast<std::uint32_t>(dbc_id & 0x1FFF'FFFFU);
    if (!m.extended && m.id > 0x7FFU) {
      fail(start, "standard message id " + std::to_string(m.id) + " exceeds 0x7FF (set bit 31 for extended ids)");
    }
    m.name = expect_identifier("message name");
    expect_punct(':', "after the message name");
    const std::uint64_t length = expect_unsigned("message length");
    if (length > 64) {
      fail(start, "message length " + std::to_string(length) + " exceeds 64 bytes");
    }
    m.length = static_cast<unsigned>(length);
    m.sender = expect_identifier("sender node");
    for (const Message& other : db_.messages) {
      if (other.id == m.id && other.extended == m.extended) {
        fail(start, "duplicate message id " + std::to_string(dbc_id) + " (" + other.name + ", " + m.name + ")");
      }
      if (other.name == m.name) {
        fail(start, "duplicate message name " + m.name);
      }
    }
    db_.messages.push_back(std::move(m));
    current_ = db_.messages.size() - 1;
  }

  void signal(const Token& start) {
    if (!current_) {
      fail(start, "SG_ outside a message (no BO_ before it)");
    }
    Signal s;
    s.name = expect_identifier("signal name");
    if (peek().kind == TokenKind::kIdentifier) {  // multiplexer indicator: M, mN or mNM
      const Token& mux = next();
      if (mux.text == "M") {
        s.is_multiplexer = true;
      } else if (mux.text.size() >= 2 && mux.text[0] == 'm') {
        std::string digits = mux.text.substr(1);
        if (!digits.empty() && digits.back() == 'M') {
          s.is_multiplexer = true;
          digits.pop_back();
        }
        std::int64_t value = 0;
        const auto [ptr, ec] = std::from_chars(digits.data(), digits.data() + digits.size(), value);
        if (digits.empty() || ec != std::errc() || ptr != digits.data() + digits.size()) {
          fail(mux, "bad multiplexer indicator '" + mux.text + "'");
        }
        s.multiplexer_value = value;
      } else {
        fail(mux, "bad multiplexer indicator '" + mux.text + "'");
      }
    }
    expect_punct(':', "after the signal name");
    const std::uint64_t start_bit = expect_unsigned("start bit");
    expect_punct('|', "between start bit and length");
    const std::uint64_t length = expect_unsigned("signal length");
    expect_punct('@', "before the byte order");
    const std::uint64_t order = expect_unsigned("byte order (0 or 1)");
    if (order > 1) {
      fail(start, "byte order must be 0 (Motorola) or 1 (Intel)");
    }
    if (!is_punct('+') && !is_punct('-')) {
      fail(peek(), "expected '+' or '-' (signedness), found " + describe(peek()));
    }
    s.is_signed = next().text == "-";
    expect_punct('(', "before factor");
    s.factor = expect_double("factor");
    expect_punct(',', "between factor and offset");
    s.offset = expect_double("offset");
    expect_punct(')', "after offset");
    expect_punct('[', "before minimum");
    s.minimum = expect_double("minimum");
    expect_punct('|', "between minimum and maximum");
    s.maximum = expect_double("maximum");
    expect_punct(']', "after maximum");
    s.unit = expect_string("unit");
    // Receivers: node names separated by ',' (or blanks), up to the end of the line.
    while (peek().kind == TokenKind::kIdentifier && peek().line == start.line &&
           keywords().count(peek().text) == 0) {
      const std::string receiver = next().text;
      if (receiver != "Vector__XXX") {
        s.receivers.push_back(receiver);
      }
      if (is_punct(',')) {
        next();
      }
    }
    if (length < 1 || length > 64) {
      fail(start, "signal " + s.name + ": length " + std::to_string(length) + " outside 1..64");
    }
    if (start_bit >= 512) {
      fail(start, "signal " + s.name + ": start bit " + std::to_string(start_bit) + " outside 0..511");
    }
    s.start_bit = static_cast<unsigned>(start_bit);
    s.length = static_cast<unsigned>(length);
    s.byte_order = order == 1 ? ByteOrder::kLittleEndian : ByteOrder::kBigEndian;
    Message& m = db_.messages[*current_];
    if (m.find_signal(s.name) != nullptr) {
      fail(start, "duplicate signal " + s.name + " in message " + m.name);
    }
    m.signals.push_back(std::move(s));
    signal_lines_[{*current_, m.signals.back().name}] = start.line;
  }

  // Optional object reference of CM_ and BA_.
  std::optional<PendingSignalRef> object_reference(const Token& start, std::string& object_kind) {
    object_kind.clear();
    if (is_word("BU_") || is_word("EV_")) {
      object_kind = next().text;
      expect_identifier("node or variable name");
      return std::nullopt;
    }
    if (is_word("BO_")) {
      object_kind = next().text;
      return PendingSignalRef{start.line, static_cast<std::uint32_t>(expect_unsigned("message id")), ""};
    }
    if (is_word("SG_")) {
      object_kind = next().text;
      PendingSignalRef ref{start.line, static_cast<std::uint32_t>(expect_unsigned("message id")), ""};
      ref.signal = expect_identifier("signal name");
      return ref;
    }
    return std::nullopt;
  }

  void comment(const Token& start) {
    std::string kind;
    std::optional<PendingSignalRef> ref = object_reference(start, kind);
    const std::string text = expect_string("comment text");
    expect_punct(';', "after CM_");
    if (ref) {
      comments_.emplace_back(*ref, text);
    } else if (kind.empty()) {
      db_.comment = text;
    }
  }

  void attribute_definition(const Token& start) {
    AttributeDefinition def;
    if (is_word("BU_") || is_word("BO_") || is_word("SG_") || is_word("EV_")) {
      def.object = next().text;
    }
    const std::string name = expect_string("attribute name");
    def.type = expect_identifier("attribute type");
    if (def.type == "ENUM") {
      while (peek().kind == TokenKind::kString) {
        def.enum_values.push_back(next().text);
        if (is_punct(',')) {
          next();
        }
      }
    } else if (def.type == "INT" || def.type == "HEX" || def.type == "FLOAT") {
      expect_double("attribute minimum");
      expect_double("attribute maximum");
    } else if (def.type != "STRING") {
      fail(start, "unknown attribute type '" + def.type + "'");
    }
    expect_punct(';', "after BA_DEF_");
    attribute_definitions_[name] = std::move(def);
  }

  void attribute(const Token& start) {
    const std::string name = expect_string("attribute name");
    std::string kind;
    std::optional<PendingSignalRef> ref = object_reference(start, kind);
    if (peek().kind != TokenKind::kNumber && peek().kind != TokenKind::kString) {
      fail(peek(), "expected a value for attribute \"" + name + "\", found " + describe(peek()));
    }
    const Token& value = next();
    expect_punct(';', "after BA_");
    if (kind == "BO_" && ref) {
      message_attributes_.push_back({*ref, name, value.text, value.kind == TokenKind::kString});
    }
  }

  void value_descriptions(const Token& start) {
    if (peek().kind != TokenKind::kNumber) {  // VAL_ of an environment variable
      skip_to_semicolon(start);
      return;
    }
    PendingSignalRef ref{start.line, static_cast<std::uint32_t>(expect_unsigned("message id")), ""};
    ref.signal = expect_identifier("signal name");
    std::vector<ValueDescription> values;
    while (peek().kind == TokenKind::kNumber) {
      ValueDescription v;
      v.value = expect_integer("value");
      v.label = expect_string("value label");
      values.push_back(std::move(v));
    }
    expect_punct(';', "after VAL_");
    value_tables_.emplace_back(ref, std::move(values));
  }

  // --- resolution ---------------------------------------------------------------------------
  Message& message_for(const PendingSignalRef& ref, std::string_view what) {
    const bool extended = (ref.dbc_id & 0x8000'0000U) != 0U;
    const std::uint32_t id = ref.dbc_id & 0x1FFF'FFFFU;
    for (Message& m : db_.messages) {
      if (m.id == id && m.extended == extended) {
        return m;
      }
    }
    throw ParseError(ref.line, std::string(what) + " refers to unknown message id " + std::to_string(ref.dbc_id));
  }
  Signal& signal_for(const PendingSignalRef& ref, std::string_view what) {
    Message& m = message_for(ref, what);
    for (Signal& s : m.signals) {
      if (s.name == ref.signal) {
        return s;
      }
    }
    throw ParseError(ref.line, std::string(what) + " refers to unknown signal " + ref.signal + " of message " + m.name);
  }

  std::optional<std::string> enum_label(const std::string& attribute, const std::string& value, bool is_string,
                                        int line) const {
    if (is_string) {
      return value;
    }
    const auto def = attribute_definitions_.find(attribute);
    std::int64_t index = 0;
    const auto [ptr, ec] = std::from_chars(value.data(), value.data() + value.size(), index);
    if (ec != std::errc() || ptr != value.data() + value.size()) {
      throw ParseError(line, "attribute " + attribute + ": expected an enumeration index, found '" + value + "'");
    }
    if (def == attribute_definitions_.end() || def->second.type != "ENUM") {
      return std::nullopt;
    }
    if (index < 0 || static_cast<std::size_t>(index) >= def->second.enum_values.size()) {
      throw ParseError(line, "attribute " + attribute + ": enumeration index " + value + " out of range");
    }
    return def->second.enum_values[static_cast<std::size_t>(index)];
  }

  static bool is_fd_format(const std::string& label) {
    return label.size() >= 6 && label.compare(label.size() - 6, 6, "CAN_FD") == 0;
  }

  // Bit positions a signal occupies (Motorola: sawtooth walk from the MSB).
  static unsigned highest_byte(const Signal& s) {
    if (s.byte_order == ByteOrder::kLittleEndian) {
      return (s.start_bit + s.length - 1U) / 8U;
    }
    unsigned pos = s.start_bit;
    unsigned highest = pos / 8U;
    for (unsigned i = 1; i < s.length; ++i) {
      pos = (pos % 8U == 0U) ? pos + 15U : pos - 1U;
      highest = std::max(highest, pos / 8U);
    }
    return highest;
  }

  void resolve() {
    for (const auto& [name, value] : pending_defaults_) {
      auto it = attribute_definitions_.find(name);
      if (it != attribute_definitions_.end()) {
        it->second.default_value = value;
      }
    }
    // Frame format: the VFrameFormat default, then each message's own value.
    bool default_fd = false;
    if (auto it = attribute_definitions_.find("VFrameFormat"); it != attribute_definitions_.end() &&
                                                                it->second.default_value) {
      default_fd = is_fd_format(*it->second.default_value);
    }
    for (Message& m : db_.messages) {
      m.fd = default_fd;
    }
    for (const auto& a : message_attributes_) {
      Message& m = message_for(a.ref, "BA_");
      if (a.name == "VFrameFormat") {
        const std::optional<std::string> label = enum_label(a.name, a.value, a.is_string, a.ref.line);
        if (label) {
          m.fd = is_fd_format(*label);
        }
      }
    }
    for (const auto& [ref, text] : comments_) {
      if (ref.signal.empty()) {
        message_for(ref, "CM_").comment = text;
      } else {
        signal_for(ref, "CM_").comment = text;
      }
    }
    for (auto& [ref, values] : value_tables_) {
      signal_for(ref, "VAL_").values = std::move(values);
    }
    for (const auto& [ref, type] : value_types_) {
      Signal& s = signal_for(ref, "SIG_VALTYPE_");
      if (type == 1) {
        if (s.length != 32) {
          throw ParseError(ref.line, "SIG_VALTYPE_ 1 (float) needs a 32-bit signal, " + s.name + " has " +
                                         std::to_string(s.length));
        }
        s.value_type = ValueType::kFloat32;
      } else if (type == 2) {
        if (s.length != 64) {
          throw ParseError(ref.line, "SIG_VALTYPE_ 2 (double) needs a 64-bit signal, " + s.name + " has " +
                                         std::to_string(s.length));
        }
        s.value_type = ValueType::kFloat64;
      }
    }
    for (auto& [ref, senders] : extra_senders_) {
      message_for(ref, "BO_TX_BU_").extra_senders = std::move(senders);
    }
    // Every signal inside its message.
    for (std::size_t i = 0; i < db_.messages.size(); ++i) {
      const Message& m = db_.messages[i];
      for (const Signal& s : m.signals) {
        if (highest_byte(s) >= m.length) {
          throw ParseError(signal_lines_.at({i, s.name}),
                           "signal " + s.name + " does not fit in the " + std::to_string(m.length) +
                               "-byte message " + m.name);
        }
      }
    }
  }

  struct MessageAttribute {
    PendingSignalRef ref;
    std::string name;
    std::string value;
    bool is_string = false;
  };

  std::vector<Token> tokens_;
  std::size_t pos_ = 0;
  Database db_;
  std::optional<std::size_t> current_;
  std::map<std::pair<std::size_t, std::string>, int> signal_lines_;
  std::map<std::string, AttributeDefinition> attribute_definitions_;
  std::vector<std::pair<std::string, std::string>> pending_defaults_;
  std::vector<MessageAttribute> message_attributes_;
  std::vector<std::pair<PendingSignalRef, std::string>> comments_;
  std::vector<std::pair<PendingSignalRef, std::vector<ValueDescription>>> value_tables_;
  std::vector<std::pair<PendingSignalRef, std::int64_t>> value_types_;
  std::vector<std::pair<PendingSignalRef, std::vector<std::string>>> extra_senders_;
};

std::int64_t sign_extend(std::uint64_t raw, unsigned length) {
  if (length >= 64U) {
    return static_cast<std::int64_t>(raw);
  }
  const std::uint64_t sign = std::uint64_t{1} << (length - 1U);
  return static_cast<std::int64_t>(raw ^ sign) - static_cast<std::int64_t>(sign);
}

// Decimals needed to show multiples of `step` exactly (0.01 -> 2, 0.05 -> 2, 1e-5 -> 5);
// for steps without a short decimal form (1/65535) one digit more than the step's magnitude.
int decimals_for(double step) {
  step = std::fabs(step);
  if (step == 0.0 || !std::isfinite(step)) {
    return 0;
  }
  double scaled = step;
  for (int d = 0; d <= 9; ++d) {
    if (std::fabs(scaled - std::round(scaled)) <= 1e-9 * std::max(1.0, scaled)) {
      return d;
    }
    scaled *= 10.0;
  }
  return std::clamp(static_cast<int>(std::ceil(-std::log10(step))) + 1, 0, 9);
}

}  // namespace

Database parse(std::string_view text) { return Parser(text).run(); }

Database load(const std::filesystem::path& path) {
  std::string text;
  if (const std::string problem = common::read_text_file(path, text); !problem.empty()) {
    throw ParseError(0, problem, path.string());
  }
  try {
    return parse(text);
  } catch (const ParseError& e) {
    throw ParseError(e.line(), e.message(), path.string());  // "file.dbc:12: message"
  }
}

std::uint64_t extract_raw_bits(const Signal& signal, std::span<const std::uint8_t> payload) {
  std::uint64_t value = 0;
  const auto bit_at = [&](unsigned pos) -> std::uint64_t {
    return (std::uint64_t{payload[pos / 8U]} >> (pos % 8U)) & 1U;
  };
  if (signal.byte_order == ByteOrder::kLittleEndian) {
    for (unsigned i = 0; i < signal.length; ++i) {
      value |= bit_at(signal.start_bit + i) << i;
    }
  } else {
    unsigned pos = signal.start_bit;  // the MSB
    for (unsigned i = 0; i < signal.length; ++i) {
      value = (value << 1U) | bit_at(pos);
      pos = (pos % 8U == 0U) ? pos + 15U : pos - 1U;
    }
  }
  return value;
}

std::optional<DecodedFrame> decode(const Database& db, const CanFrame& frame) {
  if (frame.error) {
    return std::nullopt;
  }
  const Message* message = db.find(frame.id, frame.extended);
  if (message == nullptr) {
    return std::nullopt;
  }
  DecodedFrame out;
  out.message = message;
  out.length_mismatch = frame.length != message->length;
  out.format_mismatch = frame.fd != message->fd;
  const std::size_t available = std::min<std::size_t>(frame.length, frame.data.size());
  const std::span<const std::uint8_t> payload(frame.data.data(), available);

  const auto fits = [&](const Signal& s) {
    if (s.byte_order == ByteOrder::kLittleEndian) {
      return (s.start_bit + s.length - 1U) / 8U < available;
    }
    unsigned pos = s.start_bit;
    for (unsigned i = 0; i < s.length; ++i) {
      if (pos / 8U >= available) {
        return false;
      }
      pos = (pos % 8U == 0U) ? pos + 15U : pos - 1U;
    }
    return true;
  };
  const auto decode_signal = [&](const Signal& s) {
    DecodedSignal d;
    d.signal = &s;
    const std::uint64_t bits = extract_raw_bits(s, payload);
    if (s.value_type == ValueType::kFloat32) {
      d.raw = static_cast<std::int64_t>(bits);
      d.value = static_cast<double>(std::bit_cast<float>(static_cast<std::uint32_t>(bits))) * s.factor + s.offset;
    } else if (s.value_type == ValueType::kFloat64) {
      d.raw = static_cast<std::int64_t>(bits);
      d.value = std::bit_cast<double>(bits) * s.factor + s.offset;
    } else {
      d.raw = s.is_signed ? sign_extend(bits, s.length) : static_cast<std::int64_t>(bits);
      d.value = static_cast<double>(d.raw) * s.factor + s.offset;
      d.label = s.find_value(d.raw);
    }
    return d;
  };

  // Simple multiplexing: signals marked mN appear only when the multiplexer reads N.
  std::optional<std::int64_t> mux_value;
  for (const Signal& s : message->signals) {
    if (s.is_multiplexer && !s.multiplexer_value && fits(s)) {
      mux_value = decode_signal(s).raw;
      break;
    }
  }
  for (const Signal& s : message->signals) {
    if (!fits(s)) {
      continue;
    }
    if (s.multiplexer_value && (!mux_value || *mux_value != *s.multiplexer_value)) {
      continue;
    }
    out.signals.push_back(decode_signal(s));
  }
  return out;
}

std::string format_value(const DecodedSignal& decoded) {
  const Signal& s = *decoded.signal;
  if (decoded.label != nullptr) {
    return decoded.label->label;
  }
  std::string text;
  if (s.value_type != ValueType::kInteger) {
    char buffer[64];
    const auto [ptr, ec] = std::to_chars(buffer, buffer + sizeof buffer, decoded.value);
    text.assign(buffer, ec == std::errc() ? ptr : buffer);
  } else {
    const int decimals = std::max(decimals_for(s.factor), decimals_for(s.offset));
    double value = decoded.value;
    // Avoid "-0.00" for values that round to zero.
    if (std::fabs(value) < 0.5 * std::pow(10.0, -decimals)) {
      value = 0.0;
    }
    char buffer[64];
    std::snprintf(buffer, sizeof buffer, "%.*f", decimals, value);
    text = buffer;
  }
  if (!s.unit.empty()) {
    text += ' ';
    text += s.unit;
  }
  return text;
}

std::string format_single_line(const DecodedFrame& decoded) {
  std::string out = decoded.message->name;
  out += '(';
  bool first = true;
  for (const DecodedSignal& d : decoded.signals) {
    if (!first) {
      out += ", ";
    }
    first = false;
    out += d.signal->name;
    out += ": ";
    out += format_value(d);
  }
  out += ')';
  if (decoded.length_mismatch) {
    out += " [length mismatch]";
  }
  if (decoded.format_mismatch) {
    out += decoded.message->fd ? " [expected CAN FD]" : " [expected classic CAN]";
  }
  return out;
}

}  // namespace pmsm::hal::dbc
