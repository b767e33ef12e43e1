// Nine lines: one more than the control's limit (MAX_LINES=8).
namespace bad {

int one() { return 1; }
int two() { return 2; }
int three() { return 3; }
int four() { return 4; }

}  // namespace bad
