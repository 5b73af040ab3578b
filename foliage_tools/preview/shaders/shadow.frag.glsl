// Shadow pass: depth only. Both faces of every triangle are drawn (face culling is off),
// because leaves are single-sided cards that must cast shadows whichever side faces the sun.

void main() {
}
