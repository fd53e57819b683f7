# The paper's per-colour pick-up skills, ready to serve:
#   ktbt peer serve --id teacher --knowledge examples/knowledge/colours.sbt --listen tcp/127.0.0.1:7447
# Colours as in the authors' release: 1 red, 2 green, 3 yellow, 4 blue.
# Each item is written the paper's way, flat: its conditions, then its actions
# (spec/stringbt.md, section 4). A robot that asks about TargetSeen(colour=2) is sent
# <sq><a>(PickTreasure)<a>(AssignCollectionPoint,colour=2)<e>.
<k>(prior)
    <sq>
        <c>(TargetSeen, colour=1)
        <a>(PickTreasure)
        <a>(AssignCollectionPoint, colour=1)
    <e>
    <sq>
        <c>(TargetSeen, colour=2)
        <a>(PickTreasure)
        <a>(AssignCollectionPoint, colour=2)
    <e>
    <sq>
        <c>(TargetSeen, colour=3)
        <a>(PickTreasure)
        <a>(AssignCollectionPoint, colour=3)
    <e>
    <sq>
        <c>(TargetSeen, colour=4)
        <a>(PickTreasure)
        <a>(AssignCollectionPoint, colour=4)
    <e>
<e>
