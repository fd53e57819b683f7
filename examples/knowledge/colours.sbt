# The paper's per-colour pick-up skills, ready to serve:
#   ktbt peer serve --id teacher --knowledge examples/knowledge/colours.sbt --listen tcp/127.0.0.1:7447
# Colours as in the authors' release: 1 red, 2 green, 3 yellow, 4 blue.
<k>(prior)
    <sq>
        <c>(TargetSeen, colour=1)
        <sq>
            <a>(PickTreasure)
            <a>(AssignCollectionPoint, colour=1)
        <e>
    <e>
    <sq>
        <c>(TargetSeen, colour=2)
        <sq>
            <a>(PickTreasure)
            <a>(AssignCollectionPoint, colour=2)
        <e>
    <e>
    <sq>
        <c>(TargetSeen, colour=3)
        <sq>
            <a>(PickTreasure)
            <a>(AssignCollectionPoint, colour=3)
        <e>
    <e>
    <sq>
        <c>(TargetSeen, colour=4)
        <sq>
            <a>(PickTreasure)
            <a>(AssignCollectionPoint, colour=4)
        <e>
    <e>
<e>
