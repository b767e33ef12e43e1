#include "common/expr/expr_parser.hpp"

#include <string>
#include <utility>
#include <vector>

#include "common/expr/expr_error.hpp"
#include "common/expr/expr_tokenizer.hpp"

namespace tally::expr {
namespace {

struct FunctionInfo {
  std::string_view name;
  enum { unary, binary, sum, avg, min, max } shape;
  Op op;
};

constexpr FunctionInfo kFunctions[] = {
    {"sin", FunctionInfo::unary, Op::sin},     {"cos", FunctionInfo::unary, Op::cos},
    {"tan", FunctionInfo::unary, Op::tan},     {"asin", FunctionInfo::unary, Op::asin},
    {"acos", FunctionInfo::unary, Op::acos},   {"atan", FunctionInfo::unary, Op::atan},
    {"sinh", FunctionInfo::unary, Op::sinh},   {"cosh", FunctionInfo::unary, Op::cosh},
    {"tanh", FunctionInfo::unary, Op::tanh},   {"asinh", FunctionInfo::unary, Op::asinh},
    {"acosh", FunctionInfo::unary, Op::acosh}, {"atanh", FunctionInfo::unary, Op::atanh},
    {"log2", FunctionInfo::unary, Op::log2},   {"log10", FunctionInfo::unary, Op::log10},
    {"log", FunctionInfo::unary, Op::ln},      {"ln", FunctionInfo::unary, Op::ln},
    {"exp", FunctionInfo::unary, Op::exp},     {"sqrt", FunctionInfo::unary, Op::sqrt},
    {"sign", FunctionInfo::unary, Op::sign},   {"rint", FunctionInfo::unary, Op::rint},
    {"abs", FunctionInfo::unary, Op::abs},     {"atan2", FunctionInfo::binary, Op::atan2},
    {"sum", FunctionInfo::sum, Op::add},       {"avg", FunctionInfo::avg, Op::add},
    {"min", FunctionInfo::min, Op::min2},      {"max", FunctionInfo::max, Op::max2},
};

const FunctionInfo* find_function(std::string_view name) {
  for (const auto& f : kFunctions) {
    if (f.name == name) return &f;
  }
  return nullptr;
}

}  // namespace

bool is_reserved_name(std::string_view name) {
  if (find_function(name) || name == "_pi" || name == "_e") return true;
  if (name == "x" || name == "y" || name == "z") return true;
  if (name.size() < 2 || name[0] != 'x') return false;
  for (char c : name.substr(1)) {
    if (c < '0' || c > '9') return false;
  }
  return true;
}

namespace {

class Parser {
 public:
  Parser(std::vector<Token> tokens, size_t dimensions, size_t max_depth)
      : tokens_(std::move(tokens)), dims_(dimensions), max_depth_(max_depth) {}

  Ast run() {
    if (tokens_.front().kind == TokenKind::end) {
      throw ExprError(ExprErrorKind::syntax, "expression is empty", 0);
    }
    ast_.root = parse_ternary();
    const Token& t = peek();
    if (t.kind != TokenKind::end) {
      if (t.text == ")") fail("unbalanced ')'", t);
      if (t.text == ",") fail("',' outside of a function's argument list", t);
      fail("unexpected " + describe(t) + " after a complete expression (missing operator?)", t);
    }
    return std::move(ast_);
  }

 private:
  // Nesting counter: every construct that makes the parser (and later passes) recurse
  // passes through one of these, so max_depth bounds the stack use of all passes.
  struct DepthGuard {
    DepthGuard(Parser& p, const Token& at) : parser(p) {
      if (++parser.depth_ > parser.max_depth_) {
        throw ExprError(ExprErrorKind::limit,
                        "expression is nested too deeply (limit " +
                            std::to_string(parser.max_depth_) + " levels) at position " +
                            std::to_string(at.position),
                        at.position);
      }
    }
    ~DepthGuard() { --parser.depth_; }
    DepthGuard(const DepthGuard&) = delete;
    DepthGuard& operator=(const DepthGuard&) = delete;
    Parser& parser;
  };

  const Token& peek() const { return tokens_[next_]; }
  const Token& take() { return tokens_[next_++]; }
  bool is_op(std::string_view op) const {
    return peek().kind == TokenKind::op && peek().text == op;
  }
  bool accept(std::string_view op) {
    if (!is_op(op)) return false;
    ++next_;
    return true;
  }

  [[noreturn]] static void fail(const std::string& what, const Token& at) {
    throw ExprError(ExprErrorKind::syntax,
                    what +
                        (at.kind == TokenKind::end ? " at the end of the expression (position "
                                                   : " at position ") +
                        std::to_string(at.position) + (at.kind == TokenKind::end ? ")" : ""),
                    at.position);
  }

  NodeId make_constant(double v, size_t pos) {
    Node n;
    n.kind = NodeKind::constant;
    n.value = v;
    n.position = pos;
    return ast_.add(std::move(n));
  }
  NodeId make(NodeKind kind, Op op, std::vector<NodeId> kids, size_t pos) {
    Node n;
    n.kind = kind;
    n.op = op;
    n.kids = std::move(kids);
    n.position = pos;
    return ast_.add(std::move(n));
  }

  // `at`: the token that opened the nesting ('(', ',', '?', ':'), named if it is too deep.
  NodeId parse_nested(const Token& at) {
    DepthGuard guard(*this, at);
    return parse_ternary();
  }

  NodeId parse_ternary() {
    const size_t pos = peek().position;
    NodeId cond = parse_or();
    if (!is_op("?")) return cond;
    const Token& q = take();
    NodeId then_branch = parse_nested(q);
    if (!is_op(":")) {
      fail("'?' at position " + std::to_string(q.position) + " has no matching ':', found " +
               describe(peek()),
           peek());
    }
    NodeId else_branch = parse_nested(take());
    return make(NodeKind::select, Op::select, {cond, then_branch, else_branch}, pos);
  }

  // One left-associative precedence level: operand (op operand)*.
  template <class Next, class Match>
  NodeId parse_chain(Next next, Match match) {
    const size_t pos = peek().position;
    NodeId first = (this->*next)();
    Op op{};
    if (!match(peek(), op)) return first;
    Node chain;
    chain.kind = NodeKind::chain;
    chain.position = pos;
    chain.kids.push_back(first);
    while (match(peek(), op)) {
      ++next_;
      chain.ops.push_back(op);
      chain.kids.push_back((this->*next)());
    }
    return ast_.add(std::move(chain));
  }

  static bool match_op(const Token& t, std::string_view text, Op want, Op& op) {
    if (t.kind != TokenKind::op || t.text != text) return false;
    op = want;
    return true;
  }

  NodeId parse_or() {
    return parse_chain(&Parser::parse_and,
                       [](const Token& t, Op& op) { return match_op(t, "||", Op::lor, op); });
  }
  NodeId parse_and() {
    return parse_chain(&Parser::parse_cmp,
                       [](const Token& t, Op& op) { return match_op(t, "&&", Op::land, op); });
  }
  NodeId parse_cmp() {
    return parse_chain(&Parser::parse_sum, [](const Token& t, Op& op) {
      return match_op(t, "<", Op::lt, op) || match_op(t, ">", Op::gt, op) ||
             match_op(t, "<=", Op::le, op) || match_op(t, ">=", Op::ge, op) ||
             match_op(t, "==", Op::eq, op) || match_op(t, "!=", Op::ne, op);
    });
  }
  NodeId parse_sum() {
    return parse_chain(&Parser::parse_product, [](const Token& t, Op& op) {
      return match_op(t, "+", Op::add, op) || match_op(t, "-", Op::sub, op);
    });
  }
  NodeId parse_product() {
    return parse_chain(&Parser::parse_signed, [](const Token& t, Op& op) {
      return match_op(t, "*", Op::mul, op) || match_op(t, "/", Op::div, op);
    });
  }

  NodeId parse_signed() {
    if (is_op("-") || is_op("+")) {
      const Token& sign = take();
      if (is_op("-") || is_op("+"))
        fail("a sign cannot follow a sign: unexpected " + describe(peek()), peek());
      NodeId operand = parse_power();
      if (sign.text == "+") return operand;
      return make(NodeKind::unary, Op::neg, {operand}, sign.position);
    }
    return parse_power();
  }

  NodeId parse_power() {
    const size_t pos = peek().position;
    NodeId base = parse_primary();
    if (!is_op("^")) return base;
    const Token& caret = take();
    DepthGuard guard(*this, caret);
    NodeId exponent = parse_signed();
    return make(NodeKind::binary, Op::pow, {base, exponent}, pos);
  }

  NodeId parse_primary() {
    const Token& t = peek();
    switch (t.kind) {
      case TokenKind::number:
        ++next_;
        return make_constant(t.value, t.position);
      case TokenKind::identifier:
        ++next_;
        if (is_op("(")) return parse_call(t);
        return parse_name(t);
      case TokenKind::op:
        if (t.text == "(") {
          ++next_;
          NodeId inner = parse_nested(t);
          if (!accept(")")) {
            fail("missing ')' to close '(' at position " + std::to_string(t.position) + ", found " +
                     describe(peek()),
                 peek());
          }
          return inner;
        }
        if (t.text == ")") {
          fail(next_ > 0 && tokens_[next_ - 1].text == "(" ? "empty parentheses '()'"
                                                           : "unexpected ')' where a value "
                                                             "was expected",
               t);
        }
        fail("unexpected operator " + describe(t) + " where a value was expected", t);
      case TokenKind::end:
        fail("unexpected end of expression where a value was expected", t);
    }
    fail("unexpected token", t);
  }

  std::string variables_hint() const {
    if (dims_ == 0) return " (the integrand has no variables)";
    std::string s = " (variables: x0";
    if (dims_ > 1) s += dims_ == 2 ? ", x1" : "..x" + std::to_string(dims_ - 1);
    s += ", x";
    if (dims_ > 1) s += ", y";
    if (dims_ > 2) s += ", z";
    return s + ")";
  }

  bool lookup_variable(std::string_view name, uint32_t& index) const {
    if (name == "x" || name == "y" || name == "z") {
      index = static_cast<uint32_t>(name[0] - 'x');
      return index < dims_;
    }
    if (name.size() < 2 || name.size() > 3 || name[0] != 'x') return false;
    if (name[1] == '0' && name.size() > 2) return false;  // "x01" is not x1 (muParser agrees)
    uint32_t v = 0;
    for (char c : name.substr(1)) {
      if (c < '0' || c > '9') return false;
      v = v * 10 + static_cast<uint32_t>(c - '0');
    }
    index = v;
    return v < dims_;
  }

  static bool looks_like_variable(std::string_view name) {
    if (name == "x" || name == "y" || name == "z") return true;
    if (name.size() < 2 || name[0] != 'x') return false;
    for (char c : name.substr(1)) {
      if (c < '0' || c > '9') return false;
    }
    return true;
  }

  NodeId parse_name(const Token& t) {
    if (t.text == "_pi") return make_constant(kMuParserPi, t.position);
    if (t.text == "_e") return make_constant(kMuParserE, t.position);
    uint32_t index = 0;
    if (lookup_variable(t.text, index)) {
      Node n;
      n.kind = NodeKind::variable;
      n.var = index;
      n.position = t.position;
      return ast_.add(std::move(n));
    }
    if (find_function(t.text)) {
      fail("function " + describe(t) + " needs its arguments in parentheses", t);
    }
    if (looks_like_variable(t.text)) fail("unknown variable " + describe(t) + variables_hint(), t);
    fail("unknown name " + describe(t) + variables_hint(), t);
  }

  NodeId parse_call(const Token& name) {
    const FunctionInfo* f = find_function(name.text);
    if (!f) {
      uint32_t index = 0;
      if (lookup_variable(name.text, index) || name.text == "_pi" || name.text == "_e") {
        fail(describe(name) + " is not a function", name);
      }
      fail("unknown function " + describe(name), name);
    }
    const Token& open = take();  // '('
    std::vector<NodeId> args;
    if (is_op(")")) fail("function " + describe(name) + " needs at least one argument", peek());
    const Token* opener = &open;
    while (true) {
      args.push_back(parse_nested(*opener));
      if (is_op(",")) {
        opener = &take();
        continue;
      }
      if (accept(")")) break;
      fail("missing ')' to close the arguments of " + describe(name) + " opened at position " +
               std::to_string(open.position) + ", found " + describe(peek()),
           peek());
    }
    const size_t want = f->shape == FunctionInfo::unary    ? 1
                        : f->shape == FunctionInfo::binary ? 2
                                                           : 0;
    if (want != 0 && args.size() != want) {
      fail("function " + describe(name) + " takes " + std::to_string(want) + " argument" +
               (want == 1 ? "" : "s") + ", got " + std::to_string(args.size()),
           name);
    }
    switch (f->shape) {
      case FunctionInfo::unary:
        return make(NodeKind::unary, f->op, std::move(args), name.position);
      case FunctionInfo::binary:
        return make(NodeKind::binary, f->op, std::move(args), name.position);
      case FunctionInfo::min:
      case FunctionInfo::max:
        if (args.size() == 1) return args[0];  // muParser: r = a0; r = min(r, a0) == a0
        return make_chain(f->op, std::move(args), name.position);
      case FunctionInfo::sum:
      case FunctionInfo::avg: {
        // muParser: r = 0; r += a_i (then / n for avg). The leading 0 matters for -0 only.
        const double count = static_cast<double>(args.size());
        std::vector<NodeId> terms;
        terms.reserve(args.size() + 1);
        terms.push_back(make_constant(0.0, name.position));
        for (NodeId a : args) terms.push_back(a);
        NodeId sum = make_chain(Op::add, std::move(terms), name.position);
        if (f->shape == FunctionInfo::sum) return sum;
        NodeId n = make_constant(count, name.position);
        Node div;
        div.kind = NodeKind::chain;
        div.kids = {sum, n};
        div.ops = {Op::div};
        div.position = name.position;
        return ast_.add(std::move(div));
      }
    }
    fail("unsupported function", name);
  }

  NodeId make_chain(Op op, std::vector<NodeId> kids, size_t pos) {
    Node n;
    n.kind = NodeKind::chain;
    n.position = pos;
    n.ops.assign(kids.size() - 1, op);
    n.kids = std::move(kids);
    return ast_.add(std::move(n));
  }

  std::vector<Token> tokens_;
  size_t next_ = 0;
  size_t dims_;
  size_t max_depth_;
  size_t depth_ = 0;
  Ast ast_;
};

NodeId fold(Ast& ast, NodeId id) {
  const NodeKind kind = ast[id].kind;
  auto constant = [&](NodeId k) { return ast[k].kind == NodeKind::constant; };
  auto value = [&](NodeId k) { return ast[k].value; };
  auto become_constant = [&](double v) {
    Node& n = ast[id];
    n.kind = NodeKind::constant;
    n.value = v;
    n.kids.clear();
    n.ops.clear();
    return id;
  };
  switch (kind) {
    case NodeKind::constant:
    case NodeKind::variable:
      return id;
    case NodeKind::unary: {
      NodeId k = fold(ast, ast[id].kids[0]);
      ast[id].kids[0] = k;
      if (constant(k)) return become_constant(apply_unary(ast[id].op, value(k)));
      return id;
    }
    case NodeKind::binary: {
      NodeId a = fold(ast, ast[id].kids[0]);
      NodeId b = fold(ast, ast[id].kids[1]);
      ast[id].kids = {a, b};
      if (constant(a) && constant(b))
        return become_constant(apply_binary(ast[id].op, value(a), value(b)));
      return id;
    }
    case NodeKind::chain: {
      std::vector<NodeId> kids = ast[id].kids;
      std::vector<Op> ops = ast[id].ops;
      for (NodeId& k : kids) k = fold(ast, k);
      // Only a leading run of constants folds: (x + 1) + 2 is not x + 3 in floating point.
      size_t first = 0;
      while (first + 1 < kids.size() && constant(kids[first]) && constant(kids[first + 1])) {
        ast[kids[first + 1]].value =
            apply_binary(ops[first], value(kids[first]), value(kids[first + 1]));
        ++first;
      }
      kids.erase(kids.begin(), kids.begin() + static_cast<std::ptrdiff_t>(first));
      ops.erase(ops.begin(), ops.begin() + static_cast<std::ptrdiff_t>(first));
      if (kids.size() == 1) return kids[0];
      ast[id].kids = std::move(kids);
      ast[id].ops = std::move(ops);
      return id;
    }
    case NodeKind::select: {
      NodeId c = fold(ast, ast[id].kids[0]);
      if (constant(c)) return fold(ast, ast[id].kids[select_value(value(c), 1, 2) == 1 ? 1 : 2]);
      NodeId a = fold(ast, ast[id].kids[1]);
      NodeId b = fold(ast, ast[id].kids[2]);
      ast[id].kids = {c, a, b};
      return id;
    }
  }
  return id;
}

}  // namespace

Ast parse(std::string_view text, size_t dimensions, size_t max_depth) {
  Parser parser(tokenize(text), dimensions, max_depth);
  return parser.run();
}

void fold_constants(Ast& ast) {
  ast.root = fold(ast, ast.root);
}

}  // namespace tally::expr
